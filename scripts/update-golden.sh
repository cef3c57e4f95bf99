#!/usr/bin/env bash
# Regenerates the PLANT golden file, tests/golden/plant-estimates.csv, from the native build:
#
#   build/bin/cdro-hostd --ranges-csv ../shared/data/plant/ranges.csv \
#       --heights-csv ../shared/data/plant/nodes.csv --set engine.convergence.room_excess_m=0 \
#       --out-csv tests/golden/plant-estimates.csv
#
# PLANT is one hall of an industrial plant, with no rooms, and its user says so
# (engine.convergence.room_excess_m=0; docs/engine.md): the statuses are then the checks' own,
# not the walls' prior. The positions are the same with the default (the prior only widens the
# ellipses).
#
# tests/hostd/test_plant_golden.py fails, naming the first row that differs, whenever the engine's
# output on PLANT changes by a single digit. When the change is intended (a better engine, a
# changed default), run this script, look at what moved (it prints the diff's size and the
# aligned RMSE against the survey), and commit the new file with the change that caused it, saying
# why in the commit message. When it is not intended, the test caught a regression: do not
# regenerate.
#
# The data is not in this repository: ../shared/data from the repository root, or $CDRO_DATA_DIR
# (the folder that holds plant/). The build directory is ./build, or $CDRO_BUILD_DIR.
set -euo pipefail
cd "$(dirname "$0")/.."

data="${CDRO_DATA_DIR:-../shared/data}"
build="${CDRO_BUILD_DIR:-build}"
plant="$data/plant"
golden=tests/golden/plant-estimates.csv
if [ ! -f "$plant/ranges.csv" ] || [ ! -f "$plant/nodes.csv" ]; then
  echo "update-golden: PLANT data not found at $plant (set CDRO_DATA_DIR to the folder that holds plant/)" >&2
  exit 1
fi
if [ ! -x "$build/bin/cdro-hostd" ]; then
  cmake -S . -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo > /dev/null
fi
cmake --build "$build" --target cdro-hostd > /dev/null

"$build/bin/cdro-hostd" --ranges-csv "$plant/ranges.csv" --heights-csv "$plant/nodes.csv" \
  --set engine.convergence.room_excess_m=0 --out-csv "$golden"
git --no-pager diff --stat -- "$golden" || true
if [ -x .venv/bin/cdro-eval ]; then
  .venv/bin/cdro-eval --truth "$plant/nodes.csv" --estimates "$golden" --heights-from-truth --no-baselines \
    | head -n 12 || true
fi
echo "update-golden: wrote $golden; commit it with the change that made it differ, and say why"
