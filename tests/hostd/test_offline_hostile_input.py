"""cdro-hostd's offline mode and configuration against input that is not what it should be:
files with no usable row, a directory, an endless device, a byte-order
mark, node id 0, a misspelt section name, an output path that is a link; and the reading rate.

The binary is the native build's (CDRO_BUILD_DIR; default ./build). Every timeout is a deadlock
guard, nothing depends on how fast the machine is."""
import math
import re
import subprocess

import pytest

GUARD_S = 60
NODES = {1: (0.0, 0.0), 2: (8.0, 1.0), 3: (3.0, 7.0), 4: (10.0, 9.0)}


def run(hostd, *args):
    return subprocess.run([str(hostd), *map(str, args)], capture_output=True, text=True, timeout=GUARD_S)


def good_rows(rounds=3):
    ids = sorted(NODES)
    return [f"{a},{b},{math.dist(NODES[a], NODES[b]):.4f}" for _ in range(rounds)
            for i, a in enumerate(ids) for b in ids[i + 1:]]


@pytest.mark.parametrize("name, text, message", [
    ("empty", "", "no usable row"),
    ("header only", "from,to,range_m\n", "no usable row"),
    ("comments only", "# nothing here\n\n", "no usable row"),
    ("NaN rows", "from,to,range_m\n" + "1,2,nan\n" * 50, "no usable row (50 bad rows skipped)"),
    ("all refused", "from,to,range_m\n" + "3,3,2.0\n" * 20, "none of the 20 ranges read could be used"),
])
def test_a_file_without_a_usable_row_exits_2_and_says_so(hostd, tmp_path, name, text, message):
    ranges = tmp_path / "ranges.csv"
    ranges.write_text(text)
    result = run(hostd, "--ranges-csv", ranges, "--out-csv", tmp_path / "out.csv")
    assert result.returncode == 2, (name, result.stderr)
    assert message in result.stderr, (name, result.stderr)
    assert str(ranges) in result.stderr
    assert not (tmp_path / "out.csv").exists(), "an empty map was written"


def test_a_directory_is_refused(hostd, tmp_path):
    result = run(hostd, "--ranges-csv", tmp_path, "--out-csv", tmp_path / "out.csv")
    assert result.returncode == 2, result.stderr
    assert "is a directory" in result.stderr, result.stderr


def test_an_endless_device_is_refused_at_once(hostd, tmp_path):
    result = run(hostd, "--ranges-csv", "/dev/zero", "--out-csv", tmp_path / "out.csv")
    assert result.returncode == 2, result.stderr
    assert "/dev/zero:1:" in result.stderr and "not a CSV" in result.stderr, result.stderr


def test_an_overlong_line_is_refused_without_reading_it_whole(hostd, tmp_path):
    ranges = tmp_path / "ranges.csv"
    ranges.write_text("from,to,range_m\n" + "\n".join(good_rows()) + "\n1,2," + "9" * (1 << 20) + "\n")
    result = run(hostd, "--ranges-csv", ranges, "--out-csv", tmp_path / "out.csv")
    assert result.returncode == 2, result.stderr
    assert re.search(rf"{re.escape(str(ranges))}:{2 + len(good_rows())}: a line longer than \d+ bytes",
                     result.stderr), result.stderr


def test_a_byte_order_mark_is_accepted(hostd, tmp_path):
    plain, marked = tmp_path / "plain.csv", tmp_path / "marked.csv"
    text = "from,to,range_m\n" + "\n".join(good_rows()) + "\n"
    plain.write_text(text)
    marked.write_bytes(b"\xef\xbb\xbf" + text.encode())
    a = run(hostd, "--ranges-csv", plain, "--out-csv", tmp_path / "a.csv")
    b = run(hostd, "--ranges-csv", marked, "--out-csv", tmp_path / "b.csv")
    assert a.returncode == 0 and b.returncode == 0, b.stderr
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    heights = tmp_path / "heights.csv"
    heights.write_bytes(b"\xef\xbb\xbfid,z\n1,0.5\n2,0.5\n3,0.5\n4,0.5\n")
    c = run(hostd, "--ranges-csv", plain, "--heights-csv", heights, "--out-csv", tmp_path / "c.csv")
    assert c.returncode == 0, c.stderr


def test_node_id_0_is_refused_offline_as_on_the_live_link(hostd, tmp_path):
    ranges = tmp_path / "ranges.csv"
    ranges.write_text("from,to,range_m\n" + "\n".join(good_rows()) + "\n0,2,3.0\n")
    result = run(hostd, "--ranges-csv", ranges, "--out-csv", tmp_path / "out.csv")
    assert result.returncode == 0, result.stderr
    line = 2 + len(good_rows())
    assert f"{ranges}:{line}: skipped: from '0' is not a node id (1..65535" in result.stderr, result.stderr
    ids = [int(line.split(",")[0]) for line in (tmp_path / "out.csv").read_text().splitlines()[1:]]
    assert ids == sorted(NODES)


def test_the_reading_rate_is_printed(hostd, tmp_path):
    ranges = tmp_path / "ranges.csv"
    ranges.write_text("from,to,range_m\n" + "\n".join(good_rows(200)) + "\n")
    result = run(hostd, "--ranges-csv", ranges, "--out-csv", tmp_path / "out.csv")
    assert result.returncode == 0, result.stderr
    assert re.search(rf"{re.escape(str(ranges))}: {len(good_rows(200))} rows in [0-9.]+ s \([0-9]+ rows/s\)",
                     result.stderr), result.stderr


def test_a_misspelt_section_is_an_error_with_its_line(hostd, tmp_path):
    config = tmp_path / "c.yaml"
    config.write_text("serial:\n  device: /dev/null\nengin:\n  range:\n    sigma_m: 0.1\n")
    ranges = tmp_path / "ranges.csv"
    ranges.write_text("from,to,range_m\n" + "\n".join(good_rows()) + "\n")
    for args in (["--print-config"], ["--ranges-csv", ranges, "--out-csv", tmp_path / "out.csv"],
                 ["--device", "/dev/null", "--http-port", "0"]):
        result = run(hostd, "--config", config, *args)
        assert result.returncode == 2, (args, result.stderr)
        assert f"{config}:3: unknown section 'engin'" in result.stderr, (args, result.stderr)
        assert "engine" in result.stderr.split("unknown section", 1)[1]


def test_offline_outputs_refuse_links(hostd, tmp_path):
    ranges = tmp_path / "ranges.csv"
    ranges.write_text("from,to,range_m\n" + "\n".join(good_rows()) + "\n")
    victim = tmp_path / "victim.csv"
    victim.write_text("precious\n")
    (tmp_path / "out.csv").symlink_to(victim)
    result = run(hostd, "--ranges-csv", ranges, "--out-csv", tmp_path / "out.csv")
    assert result.returncode == 2, result.stderr
    assert "symbolic link" in result.stderr, result.stderr
    assert victim.read_text() == "precious\n"
