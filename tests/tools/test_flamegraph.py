"""scripts/flamegraph.py: `perf script` samples rendered as a flame graph (the graphs themselves
are made on purpose, docs/bench.md; this checks the rendering on samples written here, and that
unusable input is refused)."""
import pathlib
import subprocess
import sys

SCRIPT = pathlib.Path(__file__).resolve().parents[2] / "scripts" / "flamegraph.py"

# Three samples of process 100: two on its main thread (tid 100), one on a worker (tid 101), in
# the layout of `perf script` with DWARF call graphs (leaf first; inlined frames marked).
SAMPLES = """\
cdro-bench-engi   100 35719.167460:    3333333 cpu-clock:ppp:
\t           bf758 Eigen::LDLT<Eigen::Matrix<double, 2, 2>, 1>::compute<Eigen::Matrix<double, 2, 2> >+0x2e8 (inlined)
\t           bf758 cdro::engine::solvePoint+0x2e8 (/build/bin/cdro-bench-engine)
\t           bcd3c cdro::engine::placementCandidates+0x21c (/build/bin/cdro-bench-engine)
\t           73ce9 cdro::engine::Engine::addRange+0x389 (/build/bin/cdro-bench-engine)
\t           15e8c (anonymous namespace)::feed+0x12c (/build/bin/cdro-bench-engine)
\tffffffffffffffff [unknown] ([unknown])

cdro-bench-engi   100 35719.187459:    3333333 cpu-clock:ppp:
\t           73ce9 cdro::engine::Engine::addRange+0x389 (/build/bin/cdro-bench-engine)
\t           15e8c (anonymous namespace)::feed+0x12c (/build/bin/cdro-bench-engine)

cdro-bench-engi   101 35719.190001:    3333333 cpu-clock:ppp:
\t           c8f32 cdro::engine::refineMap(cdro::engine::MapProblem const&)+0x5c2 (/build/bin/cdro-bench-engine)
\t           a0000 std::__future_base::_State_baseV2::_M_do_set+0x10 (/usr/lib/libstdc++.so.6)
\t           a0001 start_thread+0x10 (/usr/lib/libc.so.6)
"""


def flame(*args):
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], capture_output=True, text=True)


def test_samples_become_boxes_per_thread_kind_with_library_frames_folded(tmp_path):
    # Fixture
    samples = tmp_path / "samples.txt"
    samples.write_text(SAMPLES)
    svg = tmp_path / "out.svg"

    # Act
    result = flame("--perf-script", samples, "--out", svg, "--title", "first sweep")

    # Assert
    assert result.returncode == 0, result.stderr
    assert "3 samples, 66.7 % on the main thread" in result.stdout
    text = svg.read_text()
    assert text.startswith("<svg") and "first sweep (3 samples)" in text
    assert "<title>main thread: 2 samples, 66.7 %</title>" in text
    assert "<title>other threads: 1 samples, 33.3 %</title>" in text
    assert "<title>cdro::engine::Engine::addRange: 2 samples, 66.7 %</title>" in text
    assert "<title>cdro::engine::solvePoint: 1 samples, 33.3 %</title>" in text
    assert "<title>cdro::engine::refineMap: 1 samples, 33.3 %</title>" in text  # arguments cut
    assert "{anonymous}::feed" in text
    # The inlined Eigen frame and the thread plumbing are folded into their callers.
    assert "LDLT" not in text and "_M_do_set" not in text and "start_thread" not in text
    assert "[unknown]" not in text


def test_the_same_samples_give_the_same_bytes(tmp_path):
    # Fixture
    samples = tmp_path / "samples.txt"
    samples.write_text(SAMPLES)

    # Act
    for name in ("a.svg", "b.svg"):
        assert flame("--perf-script", samples, "--out", tmp_path / name).returncode == 0

    # Assert
    assert (tmp_path / "a.svg").read_bytes() == (tmp_path / "b.svg").read_bytes()


def test_keeping_library_frames_shows_them(tmp_path):
    # Fixture
    samples = tmp_path / "samples.txt"
    samples.write_text(SAMPLES)
    svg = tmp_path / "out.svg"

    # Act
    result = flame("--perf-script", samples, "--out", svg, "--keep-library-inlines")

    # Assert
    assert result.returncode == 0, result.stderr
    assert "Eigen::LDLT::compute" in svg.read_text()


def test_unusable_input_is_refused_with_the_reason(tmp_path):
    # Fixture
    garbage = tmp_path / "garbage.txt"
    garbage.write_text("this is not perf output\n")
    empty = tmp_path / "empty.txt"
    empty.write_text("")

    # Act
    results = {"garbage": flame("--perf-script", garbage, "--out", tmp_path / "x.svg"),
               "empty": flame("--perf-script", empty, "--out", tmp_path / "x.svg"),
               "missing": flame("--perf-script", tmp_path / "none.txt", "--out", tmp_path / "x.svg"),
               "neither": flame("--out", tmp_path / "x.svg")}

    # Assert
    for result in results.values():
        assert result.returncode == 2
    assert "line 1: not a `perf script` sample header" in results["garbage"].stderr
    assert "no samples" in results["empty"].stderr
    assert "No such file" in results["missing"].stderr
    assert "either --perf-script FILE or a command" in results["neither"].stderr
    assert not (tmp_path / "x.svg").exists()
