"""The CSV reading rules where the two languages meet: the files of tests/data/csv_rules/ and the
answers of its cases.json, which tests/csv/test_csv_rules.cpp asserts for the C++ reader
(host/csv). Here: the Python reader (cdro_tools.evaluation.inputs) driven by the manifest as the
C++ test drives csv::Reader, then the tools' own readers of those kinds (read_ranges, read_truth,
read_heights, read_estimates), which must give the same rows, problems and errors."""
import json
import pathlib

import pytest

from cdro_tools.evaluation import inputs

RULES_DIR = pathlib.Path(__file__).resolve().parents[1] / "data" / "csv_rules"
MANIFEST = json.loads((RULES_DIR / "cases.json").read_text())
CASES = MANIFEST["cases"]
KIND_FORMATS = {"ranges": inputs.RANGES_FORMAT, "truth": inputs.TRUTH_FORMAT, "heights": inputs.HEIGHTS_FORMAT,
                "estimates": inputs.ESTIMATES_FORMAT}
POLICIES = {"strict": inputs.Policy.STRICT, "lenient": inputs.Policy.LENIENT}


def case_id(case: dict) -> str:
    return f"{case['file']}-{case['kind']}-{case['mode']}"


def manifest_format(kind: str) -> inputs.Format:
    k = MANIFEST["kinds"][kind]
    return inputs.Format(tuple(k["required"]), tuple(k["optional"]), tuple(tuple(n) for n in k["headerless"]))


def expected_error(case: dict) -> str:
    error = case["error"]
    where = str(RULES_DIR / case["file"]) + ("" if error["line"] is None else f":{error['line']}")
    return f"{where}: {error['message']}"


def read_as_manifest_says(case: dict) -> tuple[list[dict], inputs.Summary]:
    """The case's file through inputs.Reader, each row read with the kind's accessors in order."""
    kind = MANIFEST["kinds"][case["kind"]]
    rows = []

    def on_row(row: inputs.Row) -> None:
        values: dict = {"line": row.line}
        for column, accessor in kind["fields"]:
            if column in kind["optional"] and not row.has(column):
                continue
            values[column] = {"number": row.number, "node_id": row.node_id, "flag": row.flag}[accessor](column)
        rows.append(values)

    with inputs.Reader(str(RULES_DIR / case["file"]), manifest_format(case["kind"]), POLICIES[case["mode"]]) as reader:
        reader.for_each(on_row)
    return rows, reader.summary


def problems_of(bad: list[inputs.BadRow]) -> list[dict]:
    return [{"line": b.line, "message": b.reason} for b in bad]


def test_that_every_fixture_is_a_case_and_every_kind_is_the_tools_format():
    files = {p.name for p in RULES_DIR.glob("*.csv")}
    assert files == {case["file"] for case in CASES}
    for kind, fmt in KIND_FORMATS.items():
        assert fmt == manifest_format(kind), kind


@pytest.mark.parametrize("case", CASES, ids=case_id)
def test_that_the_reader_gives_the_manifests_answer(case):
    if "error" in case:
        with pytest.raises(inputs.InputError) as error:
            read_as_manifest_says(case)
        assert str(error.value) == expected_error(case)
        return

    rows, summary = read_as_manifest_says(case)

    assert rows == case["rows"]
    assert summary.data_rows == case["data_rows"]
    assert summary.bad_rows == len(case["problems"])
    assert problems_of(summary.problems) == case["problems"]


def read_with_the_tools_reader(case: dict) -> tuple[list[dict], list[inputs.BadRow]]:
    """The case's file through the tool's reader of its kind, as rows comparable to the manifest's
    (lines where the reader keeps them)."""
    path, policy, bad = str(RULES_DIR / case["file"]), POLICIES[case["mode"]], []
    if case["kind"] == "ranges":
        ranges = inputs.read_ranges(path, bad, policy)
        rows = [{"line": line, "from": a, "to": b, "range_m": r} for line, a, b, r in
                zip(ranges.lines.tolist(), ranges.from_ids.tolist(), ranges.to_ids.tolist(), ranges.range_m.tolist())]
        assert ranges.rows == case["data_rows"]
    elif case["kind"] == "truth":
        xy, z = inputs.read_truth(path, bad, policy)
        rows = [{"id": i, "x": float(p[0]), "y": float(p[1]), **({"z": z[i]} if i in z else {})} for i, p in xy.items()]
    elif case["kind"] == "heights":
        rows = [{"id": i, "z": z} for i, z in inputs.read_heights(path, bad, policy=policy).items()]
    else:
        estimates = inputs.read_estimates(path, bad, policy=policy)
        rows = [{"id": i, "x": float(e.xy_m[0]), "y": float(e.xy_m[1]), "var_x": float(e.cov_m2[0, 0]),
                 "cov_xy": float(e.cov_m2[0, 1]), "var_y": float(e.cov_m2[1, 1]), "converged": e.converged}
                for i, e in estimates.items()]
    return rows, bad


@pytest.mark.parametrize("case", CASES, ids=case_id)
def test_that_the_tools_reader_of_the_kind_gives_the_manifests_answer(case):
    if "error" in case:
        with pytest.raises(inputs.InputError) as error:
            read_with_the_tools_reader(case)
        assert str(error.value) == expected_error(case)
        return

    rows, bad = read_with_the_tools_reader(case)

    # ranges keep their lines but not t (read, not kept: the file order is the order); the others
    # are maps by id
    dropped = ("t",) if case["kind"] == "ranges" else ("line",)
    expected = [{k: v for k, v in row.items() if k not in dropped} for row in case["rows"]]
    assert rows == expected
    assert problems_of(bad) == case["problems"]
    assert all(b.path == str(RULES_DIR / case["file"]) for b in bad)


def test_that_numbers_and_node_ids_parse_as_the_manifest_says():
    for text, value in MANIFEST["numbers"]:
        assert inputs.parse_number(text) == value, repr(text)
    for text, value in MANIFEST["node_ids"]:
        assert inputs.parse_node_id(text) == value, repr(text)
