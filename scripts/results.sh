#!/usr/bin/env bash
# Every figure of docs/results.md: installs what is missing, builds, runs scripts/results.py
# (PLANT in file order and shuffled, the paper's Fig. 3 setting, Plaza1/Plaza2, simulated
# cooperative and carried-node runs). A few minutes. Speed figures: scripts/bench-engine.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo > /dev/null
cmake --build build -j "$(nproc)" --target cdro-hostd
.venv/bin/python scripts/results.py
