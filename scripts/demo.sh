#!/usr/bin/env bash
# The main job: installs what is missing, builds, and runs the most complete thing that exists.
# (Replaced by the live demo once cdro-hostd reads a serial link.)
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo > /dev/null
cmake --build build -j "$(nproc)"
echo "Built. The SLAM engine and the service are not there yet; run scripts/test.sh for the tests."
