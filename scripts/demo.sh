#!/usr/bin/env bash
# The main job: installs what is missing, builds, and runs the whole system on a simulated
# network for about a minute:
#   cdro-sim --scenario demo  (7 Pozyx nodes at known heights in a 12 m x 9 m room, one of them
#                              carried 5.2 m halfway through, two NLOS links, outliers, dropouts)
#     acts as the Pozyx tag on the Uno, on a pseudo-terminal: the firmware itself runs there
#     (firmware/core built for the host, sim/host_device);
#   (the heights as measured with a tape: out/demo-heights.csv, written by cdro-sim)
#   cdro-hostd reads that pseudo-terminal as its serial port: handshake, SET_NODES/SET_SCHEDULE/
#     START, the SLAM engine, the live map over HTTP, JSON Lines, the capture, checkpoints.
# At the end: out/map.png, out/rmse.png, out/estimates.jsonl, out/demo.cdrocap, and the aligned
# RMSE against the simulator's truth.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo > /dev/null
cmake --build build -j "$(nproc)" --target cdro-hostd cdro_host_device   # cdro-sim runs the firmware (sim/host_device)

mkdir -p out
rm -f out/estimates.jsonl out/demo.cdrocap* out/checkpoint.cdrosog out/map.png out/rmse.png out/demo-*.csv
link="out/demo-tty"
port=$(.venv/bin/python -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')

# The simulated device, in real time (--speed 1): ~60 s.
.venv/bin/cdro-sim --scenario demo --pty "$link" --speed 1 \
  --truth-csv out/demo-truth.csv --heights-csv out/demo-heights.csv --tracks-csv out/demo-tracks.csv --motion-csv out/demo-motion.csv \
  > out/demo-sim.log 2>&1 &
sim=$!
hostd=""
cleanup() {
  [ -n "$hostd" ] && kill "$hostd" 2> /dev/null || true
  kill "$sim" 2> /dev/null || true
}
trap cleanup EXIT
for _ in $(seq 100); do [ -L "$link" ] && break; sleep 0.1; done
[ -L "$link" ] || { cat out/demo-sim.log; echo "demo: the simulator did not make $link" >&2; exit 1; }

echo "demo: simulated Pozyx network on $(readlink "$link"); cdro-hostd reads it as its serial port"
build/bin/cdro-hostd --config config/demo.yaml --device "$link" --heights-csv out/demo-heights.csv --http-port "$port" --progress &
hostd=$!
# The live map's address comes from cdro-hostd itself (above); the simulator ends the scenario.
wait "$sim" || true
sleep 1
kill -TERM "$hostd" 2> /dev/null || true
wait "$hostd" || true
hostd=""
tail -n 3 out/demo-sim.log

echo
echo "demo: outputs in out/: estimates.jsonl, demo.cdrocap (the capture), checkpoint.cdrosog"
.venv/bin/cdro-plot out/estimates.jsonl --truth out/demo-truth.csv --tracks out/demo-tracks.csv \
  --map out/map.png --rmse out/rmse.png --title "CDRO-SLAM demo: 7 nodes, one carried" > out/demo-eval.json
.venv/bin/python - <<'PY'
import json
report = json.load(open("out/demo-eval.json"))
print(f"demo: aligned RMSE against the simulator's truth: {report['rmse_m']:.3f} m over "
      f"{report['nodes_with_truth']} nodes (rigid fit, reflection allowed)")
for node, error in sorted(report["per_node_error_m"].items()):
    print(f"  node {node}: {error:.3f} m")
print("demo: map in out/map.png, RMSE over time in out/rmse.png")
PY
