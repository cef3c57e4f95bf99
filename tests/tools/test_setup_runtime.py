"""scripts/setup.sh --runtime: what building and running cdro-hostd and the tools needs, and
nothing of the development set; and the runtime build configures without the development
packages' CMake modules (GoogleTest, simavr)."""
import pathlib
import subprocess

REPO = pathlib.Path(__file__).resolve().parents[2]
GUARD_S = 120
DEVELOPMENT_ONLY = {"clang", "chromium", "chromium-driver", "simavr", "libsimavr-dev", "gcc-avr", "avr-libc",
                    "avrdude", "binutils-avr", "arduino-core-avr", "libgtest-dev", "libgmock-dev", "mosquitto"}
RUNTIME_FLAGS = ["-DCMAKE_BUILD_TYPE=RelWithDebInfo", "-DCDRO_BUILD_TESTS=OFF", "-DCDRO_BUILD_FIL=OFF"]


def packages(*args):
    result = subprocess.run([str(REPO / "scripts" / "setup.sh"), *args, "--list"], capture_output=True, text=True,
                            timeout=GUARD_S, check=True)
    return set(result.stdout.split())


def test_that_the_runtime_set_leaves_out_the_development_packages():
    runtime, everything = packages("--runtime"), packages()
    assert runtime and runtime < everything
    assert not runtime & DEVELOPMENT_ONLY
    assert DEVELOPMENT_ONLY <= everything
    assert {"libserial-dev", "libmosquitto-dev", "libeigen3-dev", "cmake"} <= runtime


def test_that_a_bad_option_is_refused():
    result = subprocess.run([str(REPO / "scripts" / "setup.sh"), "--runtim"], capture_output=True, text=True,
                            timeout=GUARD_S)
    assert result.returncode == 2 and "usage" in result.stderr


def test_that_the_runtime_build_needs_neither_googletest_nor_simavr(tmp_path):
    result = subprocess.run(["cmake", "-S", str(REPO), "-B", str(tmp_path / "build"), "-G", "Ninja", *RUNTIME_FLAGS],
                            capture_output=True, text=True, timeout=GUARD_S)
    assert result.returncode == 0, result.stderr
    cache = (tmp_path / "build" / "CMakeCache.txt").read_text()
    assert "SIMAVR_" not in cache and "GTest_DIR" not in cache and "LIBELF_" not in cache
    targets = subprocess.run(["ninja", "-C", str(tmp_path / "build"), "-t", "targets", "all"], capture_output=True,
                             text=True, timeout=GUARD_S, check=True).stdout
    assert "bin/cdro-hostd:" in targets
    assert "cdro-fil:" not in targets
