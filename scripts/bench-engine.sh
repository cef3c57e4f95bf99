#!/usr/bin/env bash
# The engine benchmark in one command (docs/bench.md): installs what is missing (scripts/setup.sh,
# then the optional benchmark dependency gtsam into .venv, the `bench` extra of
# tools/pyproject.toml), builds Release in build-bench/, runs cdro-bench-engine (PLANT replayed,
# random geometric networks) and the iSAM2 comparison on PLANT, and prints both tables.
# Figures only: run on purpose, never by the tests.
#
#   scripts/bench-engine.sh           the full run (several minutes on 2 cores)
#   scripts/bench-engine.sh --quick   fewer passes, repeats and draws (a check that it all runs)
#
# The JSON reports go to build-bench/bench-engine/.
set -euo pipefail
cd "$(dirname "$0")/.."

ENGINE_ARGS=()
COMPARE_ARGS=()
case "${1:-}" in
  "") ;;
  --quick)
    ENGINE_ARGS=(--passes 20 --repeat 2 --draws 1 --steady-ranges 10000)
    COMPARE_ARGS=(--passes 20 --repeat 2 --seeds 2) ;;
  *) echo "usage: scripts/bench-engine.sh [--quick]" >&2; exit 2 ;;
esac

scripts/setup.sh
if ! .venv/bin/python -c "import gtsam" 2> /dev/null; then
  echo "bench-engine: installing the optional benchmark dependency (gtsam) into .venv"
  log=.venv/pip-install-bench.log
  if ! .venv/bin/python -m pip install -e "tools[bench]" > "$log" 2>&1; then
    cat "$log"
    echo "bench-engine: installing gtsam failed (log above, also in $log)" >&2
    exit 1
  fi
fi

cmake -S . -B build-bench -G Ninja -DCMAKE_BUILD_TYPE=Release > /dev/null
cmake --build build-bench -j "$(nproc)" --target cdro-bench-engine
out=build-bench/bench-engine
mkdir -p "$out"

printf '\n=== cdro-bench-engine: PLANT replayed, random geometric networks\n'
# A crash or a non-finite estimate makes it exit non-zero: the comparison still runs, and this
# script's exit status says so at the end.
status=0
build-bench/bin/cdro-bench-engine "${ENGINE_ARGS[@]}" --json-out "$out/engine.json" || status=$?

printf '\n=== PLANT: CDRO engine against GTSAM iSAM2, in one invocation\n'
.venv/bin/python bench/engine/isam2_compare.py --engine-bin build-bench/bin/cdro-bench-engine \
  "${COMPARE_ARGS[@]}" --json "$out/isam2.json"
printf '\nJSON reports: %s/engine.json, %s/isam2.json\n' "$out" "$out"
if [ "$status" != 0 ]; then
  echo "bench-engine: cdro-bench-engine exited with status $status (see above)" >&2
fi
exit "$status"
