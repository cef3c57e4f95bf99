#!/usr/bin/env bash
# clang-format (style in .clang-format) over our own C and C++: every tracked .c, .h, .cpp and
# .hpp of the tree (there is no third-party code in it), or the FILEs given.
#
#   scripts/format.sh [FILE...]           format in place
#   scripts/format.sh --check [FILE...]   change nothing; list what would change, exit 1 if any
set -euo pipefail
cd "$(dirname "$0")/.."

check=0
if [ "${1:-}" = "--check" ]; then
  check=1
  shift
fi
if [ $# -gt 0 ]; then
  files=("$@")
else
  mapfile -t files < <(git ls-files -- '*.c' '*.h' '*.cpp' '*.hpp')
fi

if [ "$check" = 0 ]; then
  printf '%s\0' "${files[@]}" | xargs -0 -P "$(nproc)" -n 16 clang-format -i --style=file
  exit 0
fi
# --dry-run --Werror: one error per change, each with its file and line.
if ! printf '%s\0' "${files[@]}" | xargs -0 -P "$(nproc)" -n 16 clang-format --dry-run --Werror --style=file; then
  echo "format: the files above differ from .clang-format; scripts/format.sh formats them" >&2
  exit 1
fi
echo "format: ${#files[@]} files as .clang-format wants them"
