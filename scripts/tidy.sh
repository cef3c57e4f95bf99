#!/usr/bin/env bash
# clang-tidy (checks in .clang-tidy, every finding an error) over our own C and C++: each
# translation unit of the native build's compile_commands.json that lives in this tree, and our
# headers they include. Not the files the build generates (the embedded web assets), not
# third-party headers; not the AVR-only binding firmware/arduino/cdro_arduino.cpp, which the
# native build does not compile. Step 1 of scripts/test.sh runs it after the native build.
#
#   scripts/tidy.sh [BUILD_DIR] [FILE...]   BUILD_DIR defaults to build; FILEs narrow the run
#
# Prints only the translation units with findings, then the time taken; exit status 1 on any.
set -euo pipefail
cd "$(dirname "$0")/.."

build=${1:-build}
shift || true
if [ ! -f "$build/compile_commands.json" ]; then
  echo "tidy: no $build/compile_commands.json; configure the native build first (README)" >&2
  exit 2
fi
root=$PWD
mapfile -t units < <(python3 - "$build/compile_commands.json" "$root" "$@" <<'EOF'
import json, os, sys
database, root, wanted = sys.argv[1], sys.argv[2], [os.path.abspath(f) for f in sys.argv[3:]]
build = os.path.dirname(os.path.abspath(database))
files = set()
for entry in json.load(open(database)):
    path = os.path.normpath(os.path.join(entry["directory"], entry["file"]))
    if path.startswith(root + os.sep) and not path.startswith(build + os.sep):
        files.add(path)
for path in sorted(files):
    if not wanted or path in wanted:
        print(path)
EOF
)
if [ ${#units[@]} = 0 ]; then
  echo "tidy: no translation unit to check" >&2
  exit 2
fi

start=$(date +%s)
# One clang-tidy per unit, as many at a time as there are cores; a unit's output is printed in
# one piece, and only when it has findings.
status=0
printf '%s\0' "${units[@]}" | xargs -0 -P "$(nproc)" -n 1 sh -c '
  out=$(clang-tidy -p "$0" --quiet "$1" 2>&1) || { printf "%s\n\n" "$out"; exit 1; }' "$build" || status=1
echo "tidy: ${#units[@]} translation units in $(( $(date +%s) - start )) s$([ $status = 0 ] && echo ", no findings")"
exit $status
