#!/usr/bin/env bash
# Installs what is missing, builds everything and runs every test, stopping at the first failure:
#   1. the C and C++ laid out as .clang-format says (scripts/format.sh --check), the native build
#      (warnings as errors), clang-tidy over it (scripts/tidy.sh, .clang-tidy, every finding an
#      error), and its CTest suites
#   2. the same suites built with AddressSanitizer + UndefinedBehaviorSanitizer
#   3. AVR cross builds with avr-gcc: the Uno image (with its flash/RAM budget) and the Mega image
#   4. libFuzzer on the frame decoder: a short run with a fixed seed and a fixed number of inputs
#   5. ruff (ruff.toml) over the Python of tools/, tests/, scripts/ and bench/, then pytest: the
#      Python tools, the end-to-end tests against the native build, and firmware in the loop
#      (tests/fil: the Uno image of step 3 in simavr, cdro-fil of step 1)
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh

JOBS=$(nproc)
step() { printf '\n=== %s\n' "$*"; }
# CTest's own lines, then its ten slowest tests, so a test that grows slow is seen.
ctest_timed() {
  local log
  log=$(mktemp)
  ctest "$@" | tee "$log"
  echo "slowest:"
  # sed reads to the end (head would close the pipe early: SIGPIPE under pipefail)
  grep -E 'Test +#[0-9]+: .* sec$' "$log" | awk '{print $(NF-1), $4}' | sort -rn | sed -n '1,10s/^/  /p'
  rm -f "$log"
}

step "1/5 clang-format + native build + clang-tidy + tests"
scripts/format.sh --check
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo > /dev/null
cmake --build build -j "$JOBS"
scripts/tidy.sh build
ctest_timed --test-dir build --output-on-failure -j "$JOBS"

step "2/5 ASan + UBSan build + tests"
cmake -S . -B build-asan -G Ninja -DCMAKE_BUILD_TYPE=Debug -DCDRO_SANITIZE=ON > /dev/null
cmake --build build-asan -j "$JOBS"
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ctest_timed --test-dir build-asan --output-on-failure -j "$JOBS"

step "3/5 AVR cross builds: Uno (ATmega328P, budget enforced) and Mega 2560"
cmake -S . -B build-avr -G Ninja --toolchain cmake/avr-gcc.cmake -DCMAKE_BUILD_TYPE=MinSizeRel > /dev/null
cmake --build build-avr -j "$JOBS"
cmake -S . -B build-avr-mega -G Ninja --toolchain cmake/avr-gcc.cmake -DCMAKE_BUILD_TYPE=MinSizeRel \
  -DCDRO_AVR_BOARD=mega > /dev/null
cmake --build build-avr-mega -j "$JOBS"

step "4/5 libFuzzer: frame decoder"
cmake -S . -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCDRO_FUZZ=ON -DCDRO_BUILD_TESTS=OFF \
  -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ > /dev/null
cmake --build build-fuzz -j "$JOBS" --target cdro-fuzz-decoder
rm -rf build-fuzz/corpus && mkdir -p build-fuzz/corpus
if ! build-fuzz/bin/cdro-fuzz-decoder -seed=1 -runs=300000 -max_len=512 -artifact_prefix=build-fuzz/ \
     build-fuzz/corpus tests/fuzz/seeds > build-fuzz/fuzz.log 2>&1; then
  tail -n 60 build-fuzz/fuzz.log
  echo "fuzzer found a failure; the input is in build-fuzz/ (crash-*), the log in build-fuzz/fuzz.log" >&2
  exit 1
fi
grep -E "^Done [0-9]+ runs" build-fuzz/fuzz.log

step "5/5 ruff + pytest"
.venv/bin/ruff check tools tests scripts bench
CDRO_BUILD_DIR="$PWD/build" CDRO_AVR_BUILD_DIR="$PWD/build-avr" .venv/bin/python -m pytest -q --durations=10 tests

printf '\nAll tests passed.\n'
