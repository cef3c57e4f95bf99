"""Every path of this repository that its own text names is there: a comment, a docstring, a
document or a configuration file that says where something is (host/hostd/src/engine_config.cpp,
docs/outputs.schema.json) names a file or folder that exists, from the repository's root or from
the naming file's own folder (a document's relative link). A file that moves or goes takes its
references with it, or this test names each stale reference and the line it is on.

A path is a word starting with one of the repository's top-level folders and a slash; a path
followed by `*`, `{` or `<` is a pattern or a placeholder, not a name, and is not checked."""
from __future__ import annotations

import pathlib
import re
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
TOP_FOLDERS = ("bench", "cmake", "common", "config", "docs", "firmware", "host", "scripts", "sim", "tests", "tools")
PATH = re.compile(r"(?<![\w./$~-])(?:%s)/[\w./-]*" % "|".join(TOP_FOLDERS))
NOT_A_NAME = "*{<"
# Data and binary files name no paths of ours (and a CSV's text is not prose); this file names
# missing paths on purpose.
SKIPPED_PREFIXES = ("tests/data/", "tests/golden/", "tests/tools/test_repository_paths.py")
SKIPPED_SUFFIXES = (".bin", ".cap", ".ckpt", ".csv", ".gz", ".ico", ".jpg", ".png", ".svg")
# (file, path): names that are not meant to exist, each with its reason.
NOT_MEANT_TO_EXIST = {
    # the usage example's output file: a flame graph the reader is about to draw
    ("scripts/flamegraph.py", "docs/bench/x.svg"),
}
# (file, path): stale names this branch may not mend; each goes when its file is mended (the test
# then fails until it is removed here, so that the list cannot hold a name that is right).
KNOWN_STALE: set = set()


def tracked_files() -> list[str]:
    try:
        listed = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True, check=True, timeout=60)
    except (OSError, subprocess.CalledProcessError) as error:
        pytest.skip(f"not a git checkout ({error}): the tracked files are unknown")
    return listed.stdout.splitlines()


def named_paths(text: str) -> list[tuple[int, str]]:
    """(line number, path) of every path `text` names (see the module's docstring)."""
    found = []
    for number, line in enumerate(text.splitlines(), 1):
        for match in PATH.finditer(line):
            if match.end() < len(line) and line[match.end()] in NOT_A_NAME:
                continue
            found.append((number, match.group(0).rstrip("./-")))
    return found


def stale_references(root: pathlib.Path, files: list[str]) -> dict[tuple[str, str], list[int]]:
    """{(file, path): line numbers} of the paths named in `files` (relative to `root`) that exist
    neither from the root nor from the naming file's folder."""
    existing = set(files)
    for name in files:
        parts = name.split("/")
        existing.update("/".join(parts[:k]) for k in range(1, len(parts)))
    stale: dict[tuple[str, str], list[int]] = {}
    for name in files:
        if name.startswith(SKIPPED_PREFIXES) or name.endswith(SKIPPED_SUFFIXES):
            continue
        try:
            text = (root / name).read_text(encoding="utf-8")
        except (UnicodeDecodeError, OSError):  # not text, or not a file of this work tree
            continue
        folder = pathlib.PurePosixPath(name).parent
        for number, path in named_paths(text):
            beside = str(folder / path) if str(folder) != "." else path
            if path not in existing and beside not in existing:
                stale.setdefault((name, path), []).append(number)
    return stale


def test_the_path_pattern_finds_names_and_leaves_patterns_and_other_trees_alone():
    text = ("// see host/hostd/src/engine_config.cpp, and docs/engine.md.\n"
            "# tests/fil/test_fil_*.py, host/engine/src/<unit>.cpp, ../shared/docs/algorithm.md\n"
            "cdro/netgen/track.hpp build/bin/cdro-hostd $CDRO_BUILD_DIR/bin docs/bench/x.svg\n")
    assert named_paths(text) == [(1, "host/hostd/src/engine_config.cpp"), (1, "docs/engine.md"),
                                 (3, "docs/bench/x.svg")]


def test_a_reference_to_a_path_that_is_not_there_is_found(tmp_path):
    files = {"docs/guide.md": "host/app/src/main.cpp, host/app/src/gone.cpp; [a plot](bench/a.svg)\n",
             "docs/bench/a.svg": "", "host/app/src/main.cpp": "// docs/guide.md, sim/moved.c\n"}
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    assert stale_references(tmp_path, sorted(files)) == {("docs/guide.md", "host/app/src/gone.cpp"): [1],
                                                          ("host/app/src/main.cpp", "sim/moved.c"): [1]}


def test_every_path_the_repository_names_is_there():
    stale = stale_references(REPO, tracked_files())
    unexpected = {key: lines for key, lines in stale.items() if key not in NOT_MEANT_TO_EXIST | KNOWN_STALE}
    report = "\n".join(f"  {name}:{','.join(map(str, lines))}: {path}"
                       for (name, path), lines in sorted(unexpected.items()))
    assert not unexpected, f"paths named in the repository that are not there:\n{report}"
    mended = sorted(KNOWN_STALE - stale.keys())
    assert not mended, f"KNOWN_STALE names references that are right now: remove them from this test: {mended}"
