#!/usr/bin/env bash
# Installs what is missing, and only that: Debian packages (apt-get, as root or via sudo) and the
# Python tools into ./.venv. Idempotent; quick when everything is already there.
#
#   scripts/setup.sh                    everything: build, tests, demo, firmware, benchmarks
#   scripts/setup.sh --runtime          only what building and running cdro-hostd and the Python
#                                       tools needs (no clang, Chromium, simavr, AVR toolchain,
#                                       GoogleTest, pytest); build with the README's runtime flags
#   scripts/setup.sh [--runtime] --list the Debian packages of that set, one a line; installs nothing
set -euo pipefail
cd "$(dirname "$0")/.."

runtime=0
list=0
for arg in "$@"; do
  case "$arg" in
    --runtime) runtime=1 ;;
    --list) list=1 ;;
    *) echo "usage: scripts/setup.sh [--runtime] [--list]" >&2; exit 2 ;;
  esac
done

SUDO=""
if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi

# What building and running the service and the tools needs, from Debian 12.
RUNTIME_PACKAGES=(
  build-essential cmake ninja-build pkg-config git
  python3 python3-venv python3-pip
  # the Python tools' dependencies, which their environment from `cmake --install` takes from the
  # system (docs/deployment.md, "The Python tools")
  python3-numpy python3-scipy python3-matplotlib python3-serial python3-yaml python3-paho-mqtt
  libeigen3-dev
  libserial-dev libcli11-dev libspdlog-dev nlohmann-json3-dev libcpp-httplib-dev libyaml-cpp-dev
  # sd_notify (Type=notify, the watchdog): config/systemd/cdro-hostd.service.in
  libmosquitto-dev
  libsystemd-dev
)
# Everything the build, the tests, the demo and the firmware need besides (mosquitto, openssl:
# the MQTT tests' broker and its certificate; systemd: systemd-analyze verify of the unit).
DEVELOPMENT_PACKAGES=(
  libgtest-dev libgmock-dev
  mosquitto openssl
  systemd
  clang libclang-rt-14-dev
  # scripts/tidy.sh (a step of scripts/test.sh) and scripts/format.sh
  clang-tidy clang-format
  gcc-avr avr-libc arduino-core-avr binutils-avr avrdude
  simavr libsimavr-dev libelf-dev
  chromium chromium-driver
)
DEB_PACKAGES=("${RUNTIME_PACKAGES[@]}")
extras="[dev]"
if [ "$runtime" = 0 ]; then
  DEB_PACKAGES+=("${DEVELOPMENT_PACKAGES[@]}")
else
  extras=""
fi
if [ "$list" = 1 ]; then
  printf '%s\n' "${DEB_PACKAGES[@]}"
  exit 0
fi

missing=()
for p in "${DEB_PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing Debian packages: ${missing[*]}"
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get update -q
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${missing[@]}"
fi

# Python tools in a virtual environment, reinstalled only when tools/pyproject.toml changes.
PY=/usr/bin/python3
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv"
  "$PY" -m venv .venv
fi
stamp=.venv/.cdro-tools-installed
want="$(sha256sum tools/pyproject.toml | cut -d' ' -f1) tools$extras"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "setup: installing the Python tools into .venv"
  log=.venv/pip-install.log
  if ! { .venv/bin/python -m pip install --upgrade pip && .venv/bin/python -m pip install -e "tools$extras"; } > "$log" 2>&1; then
    cat "$log"
    echo "setup: installing the Python tools failed (log above, also in $log)" >&2
    exit 1
  fi
  echo "$want" > "$stamp"
fi
