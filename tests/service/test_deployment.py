"""cdro-hostd as a system service (docs/deployment.md): what `cmake --install` puts where (the
Python tools' environment and commands too) and the unit's check by systemd-analyze; the
sd_notify protocol (READY=1, WATCHDOG=1, STOPPING=1) on a socket the test owns; journald
priorities on stderr; `--version` here and in every Python tool; `--print-config`. Timeouts
are deadlock guards only."""
from __future__ import annotations

import os
import pathlib
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import tomllib

import pytest
import yaml

from cdro_tools.codec.layout import CONSTANTS
from service_support import free_port, wait_until

REPO = pathlib.Path(__file__).resolve().parents[2]
GUARD_S = 60.0
PYTHON_TOOLS = sorted(tomllib.loads((REPO / "tools" / "pyproject.toml").read_text())["project"]["scripts"])
VERSION_TAIL = (f"(protocol {CONSTANTS['CDRO_PROTOCOL_VERSION']}, frame layout 0x{CONSTANTS['CDRO_LAYOUT_HASH']:04X}, "
                f"checkpoint layout 0x{CONSTANTS['CDRO_SOG_LAYOUT_HASH']:04X})")


def quiet_service_args(tmp_path, **overrides):
    """A live service with no board (it waits for one), nothing written but what a test asks."""
    args = {"--device": str(tmp_path / "no-board"), "--capture": "", "--checkpoint": "", "--jsonl": "",
            "--http-port": "0"}
    args.update(overrides)
    return [item for pair in args.items() for item in pair]


# ---- cmake --install ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def staging(tmp_path_factory, build_dir):
    root = tmp_path_factory.mktemp("staging")
    if not (build_dir / "cmake_install.cmake").exists():
        pytest.fail(f"{build_dir} is not a configured build")
    result = subprocess.run(["cmake", "--install", str(build_dir), "--prefix", "/usr"], capture_output=True, text=True,
                            timeout=GUARD_S, env={**os.environ, "DESTDIR": str(root)})
    assert result.returncode == 0, result.stdout + result.stderr
    return root


def test_that_install_puts_the_service_its_unit_user_udev_rule_config_and_docs_in_place(staging):
    # Act
    unit = (staging / "usr/lib/systemd/system/cdro-hostd.service").read_text()
    sysusers = (staging / "usr/lib/sysusers.d/cdro-slam.conf").read_text()
    rules = (staging / "usr/lib/udev/rules.d/99-cdro-pozyx.rules").read_text()

    # Assert
    assert os.access(staging / "usr/bin/cdro-hostd", os.X_OK)
    assert (staging / "usr/share/doc/cdro-slam/examples/cdro-hostd.example.yaml").is_file()
    for line in ("Type=notify", "WatchdogSec=30", "RestartPreventExitStatus=2", "User=cdro",
                 "SupplementaryGroups=dialout"):
        assert re.search(rf"^{re.escape(line)}$", unit, re.M), line
    assert "exec /usr/bin/cdro-hostd --config /etc/cdro/cdro-hostd.yaml" in unit
    documentation = re.search(r"^Documentation=(.*)$", unit, re.M).group(1).split()
    assert documentation
    for url in documentation:
        assert url.startswith("file:///usr/share/doc/cdro-slam/"), url
        assert (staging / url.removeprefix("file:///")).is_file(), f"{url} is not installed"
    assert re.search(r"^u cdro - .* /var/lib/cdro$", sysusers, re.M)
    assert re.search(r"^m cdro dialout$", sysusers, re.M)
    board_rules = [line for line in rules.splitlines() if line.startswith("SUBSYSTEM") and "SYMLINK" in line]
    assert len(board_rules) == 3
    for line in board_rules:
        assert 'SYMLINK+="cdro-tag"' in line and 'GROUP="dialout"' in line and 'MODE="0660"' in line
        assert 'ENV{ID_MM_DEVICE_IGNORE}="1"' in line
    assert any('ATTRS{idVendor}=="1a86", ATTRS{idProduct}=="7523"' in line for line in board_rules)  # CH340 clones


def test_that_install_puts_every_python_tool_in_bin_pointing_at_the_final_prefix(staging):
    # Fixture
    venv = pathlib.Path("/usr/lib/cdro/venv")

    # Act
    links = {name: staging / "usr/bin" / name for name in PYTHON_TOOLS}
    config = (staging / "usr/lib/cdro/venv/pyvenv.cfg").read_text()

    # Assert
    assert len(links) >= 11
    for name, link in links.items():
        assert link.is_symlink(), f"{link} is not installed"
        target = pathlib.Path(os.path.normpath(pathlib.Path("/usr/bin") / os.readlink(link)))
        assert target == venv / "bin" / name, (name, os.readlink(link))
        script = staging / target.relative_to("/")
        assert os.access(script, os.X_OK), script
        assert script.read_text().splitlines()[0] == f"#!{venv}/bin/python", name
    assert re.search(r"^include-system-site-packages = true$", config, re.M)   # Debian's numpy, scipy, ...
    assert (staging / "usr/lib/cdro/venv/bin/python").is_symlink()
    assert list((staging / "usr/lib/cdro/venv/lib").glob("python3.*/site-packages/cdro_tools-*.dist-info/METADATA"))
    staging_path = str(staging).encode()
    for path in (staging / "usr/lib/cdro/venv").rglob("*"):
        if path.is_file() and not path.is_symlink():
            assert staging_path not in path.read_bytes(), f"{path} names the staging root"


def test_that_the_installed_python_tools_run_from_their_environment(build_dir, tmp_path):
    # Fixture: the environment's paths are the final ones, so this install is where it runs
    prefix = tmp_path / "prefix"
    missing = subprocess.run(["/usr/bin/python3", "-c", "import numpy, scipy, serial, yaml"], capture_output=True,
                             text=True)
    if missing.returncode != 0:
        pytest.fail("the tools' Debian dependencies are missing (scripts/setup.sh --runtime installs "
                    f"python3-numpy, python3-serial, ...): {missing.stderr.strip()}")
    install = subprocess.run(["cmake", "--install", str(build_dir), "--prefix", str(prefix), "--component",
                              "python-tools"], capture_output=True, text=True, timeout=GUARD_S,
                             env={k: v for k, v in os.environ.items() if k != "DESTDIR"})
    assert install.returncode == 0, install.stdout + install.stderr

    # Act
    version = subprocess.run([str(prefix / "bin/cdro-eval"), "--version"], capture_output=True, text=True,
                             timeout=GUARD_S, env={"PATH": "/usr/bin:/bin"})
    usage = subprocess.run([str(prefix / "bin/cdro-sim"), "--help"], capture_output=True, text=True,
                           timeout=GUARD_S, env={"PATH": "/usr/bin:/bin"})
    where = subprocess.run([str(prefix / "lib/cdro/venv/bin/python"), "-c",
                            "import cdro_tools, numpy; print(cdro_tools.__file__); print(numpy.__file__)"],
                           capture_output=True, text=True, timeout=GUARD_S)
    # cdro-sim runs the firmware from the library installed beside the environment. A sanitizer
    # build's library is installed too, but ASan cannot be loaded into an uninstrumented Python:
    # there the install is checked and the plain build's run of this test runs it.
    sanitized = "CDRO_SANITIZE:BOOL=ON" in (build_dir / "CMakeCache.txt").read_text(errors="replace")
    if sanitized:
        assert (prefix / "lib/cdro/libcdro_host_device.so").is_file()
    device = None if sanitized else subprocess.run([str(prefix / "lib/cdro/venv/bin/python"), "-c",
                             "from cdro_tools.simulation import host_device; print(host_device.library()._name)"],
                            capture_output=True, text=True, timeout=GUARD_S, env={"PATH": "/usr/bin:/bin"})
    simulated = None if sanitized else subprocess.run(
        [str(prefix / "bin/cdro-sim"), "--scenario", "demo", "--duration", "2", "--ranges-csv",
         str(tmp_path / "ranges.csv")], capture_output=True, text=True, timeout=GUARD_S, env={"PATH": "/usr/bin:/bin"})

    # Assert
    assert version.returncode == 0, version.stderr
    assert version.stdout.strip() == f"cdro-eval 0.1.0 {VERSION_TAIL}"
    assert usage.returncode == 0, usage.stderr
    assert usage.stdout.startswith("usage: cdro-sim") and "--version" in usage.stdout
    package, numpy = where.stdout.split()
    assert pathlib.Path(package).is_relative_to(prefix / "lib/cdro/venv")      # the installed copy, not tools/
    assert not pathlib.Path(numpy).is_relative_to(prefix), numpy                 # the system's: nothing downloaded
    if device is not None and simulated is not None:
        assert device.returncode == 0, device.stderr
        assert pathlib.Path(device.stdout.strip()) == prefix / "lib/cdro/libcdro_host_device.so"
        assert simulated.returncode == 0, simulated.stderr
        assert len((tmp_path / "ranges.csv").read_text().splitlines()) > 1          # a header and ranges


def test_that_systemd_analyze_verifies_the_installed_unit(staging, tmp_path):
    # Fixture
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze is not installed (Debian package systemd; scripts/setup.sh installs it)")
    unit = staging / "usr/lib/systemd/system/cdro-hostd.service"
    mangled = tmp_path / "cdro-mangled.service"  # a misspelt key, which verify must report
    mangled.write_text(unit.read_text().replace("RestartPreventExitStatus=", "RestartPreventExitStatuss="))

    # Act: the unit as systemd loads it (against this system's targets and /bin/sh, which ExecStart runs)
    result = subprocess.run([analyze, "verify", str(unit)], capture_output=True, text=True, timeout=GUARD_S)
    broken = subprocess.run([analyze, "verify", str(mangled)], capture_output=True, text=True, timeout=GUARD_S)

    # Assert
    assert result.returncode == 0, result.stdout + result.stderr
    assert "cdro-hostd.service" not in result.stdout + result.stderr  # no warning about it either
    assert "Unknown key 'RestartPreventExitStatuss'" in broken.stderr, "verify did not read the unit: the check is void"


# ---- sd_notify --------------------------------------------------------------------------------------

class NotifySocket:
    """The service manager's end of sd_notify: a unix datagram socket; messages as they came."""

    def __init__(self, path: pathlib.Path):
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.settimeout(0.05)
        self.messages: list[dict[str, str]] = []

    def drain(self) -> list[dict[str, str]]:
        while True:
            try:
                data = self.sock.recv(4096)
            except (TimeoutError, socket.timeout):
                return self.messages
            self.messages.append(dict(line.split("=", 1) for line in data.decode().splitlines() if "=" in line))

    def count(self, key: str, value: str = "1") -> int:
        return sum(1 for m in self.drain() if m.get(key) == value)

    def close(self):
        self.sock.close()


def test_that_the_service_notifies_ready_watchdog_status_and_stopping(hostd, tmp_path):
    # Fixture
    notify = NotifySocket(tmp_path / "notify.sock")
    port = free_port()
    env = {**os.environ, "NOTIFY_SOCKET": str(notify.path), "WATCHDOG_USEC": "200000"}  # ping every 0.1 s
    env.pop("WATCHDOG_PID", None)
    process = subprocess.Popen([str(hostd), *quiet_service_args(tmp_path, **{"--http-port": str(port)})],
                               cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        # Act
        wait_until(lambda: notify.count("READY") == 1, "READY=1", GUARD_S)
        with socket.create_connection(("127.0.0.1", port), timeout=5):
            pass  # listening when it said it was ready
        ready = next(m for m in notify.messages if m.get("READY") == "1")
        pings_before = notify.count("WATCHDOG")
        time.sleep(1.0)
        pings = notify.count("WATCHDOG") - pings_before
        process.send_signal(signal.SIGTERM)
        status = process.wait(timeout=GUARD_S)
        notify.drain()
    finally:
        if process.poll() is None:
            process.kill()
        notify.close()

    # Assert
    assert status == 0, process.stderr.read()
    assert "disconnected" in ready["STATUS"] and f"127.0.0.1:{port}" in ready["STATUS"], ready
    assert 5 <= pings <= 15, f"{pings} WATCHDOG=1 in 1 s at WATCHDOG_USEC=0.2 s (expected every 0.1 s)"
    assert [m for m in notify.messages if m.get("STOPPING") == "1"], notify.messages
    assert notify.messages.index(ready) == 0


def test_that_without_a_watchdog_there_are_no_pings(hostd, tmp_path):
    # Fixture
    notify = NotifySocket(tmp_path / "notify.sock")
    env = {**os.environ, "NOTIFY_SOCKET": str(notify.path)}
    env.pop("WATCHDOG_USEC", None)
    process = subprocess.Popen([str(hostd), *quiet_service_args(tmp_path)], cwd=tmp_path, env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        # Act
        wait_until(lambda: notify.count("READY") == 1, "READY=1", GUARD_S)
        time.sleep(0.5)
        process.send_signal(signal.SIGTERM)
        process.wait(timeout=GUARD_S)
    finally:
        if process.poll() is None:
            process.kill()

    # Assert
    assert notify.count("WATCHDOG") == 0
    notify.close()


def test_that_a_configuration_error_exits_2_which_the_unit_does_not_restart(hostd, tmp_path):
    # Fixture
    config = tmp_path / "bad.yaml"
    config.write_text("jsonl:\n  max_node_rate_hz: -1\n")

    # Act
    result = subprocess.run([str(hostd), "--config", str(config), *quiet_service_args(tmp_path)], cwd=tmp_path,
                            capture_output=True, text=True, timeout=GUARD_S)

    # Assert
    assert result.returncode == 2
    assert f"{config}:2" in result.stderr and "max_node_rate_hz" in result.stderr
    unit = (REPO / "config/systemd/cdro-hostd.service.in").read_text()
    assert re.search(r"^RestartPreventExitStatus=2$", unit, re.M)


# ---- journald priorities ---------------------------------------------------------------------------

def run_briefly_with_stderr_in(hostd, tmp_path, stderr_path: pathlib.Path, journal_stream: str | None) -> str:
    env = dict(os.environ)
    env.pop("JOURNAL_STREAM", None)
    with open(stderr_path, "w") as stderr:
        if journal_stream is not None:
            env["JOURNAL_STREAM"] = journal_stream(stderr) if callable(journal_stream) else journal_stream
        process = subprocess.Popen([str(hostd), *quiet_service_args(tmp_path)], cwd=tmp_path, env=env,
                                   stdout=subprocess.DEVNULL, stderr=stderr)
        try:
            # The missing board is reported (a warning) and retried; then a clean stop.
            wait_until(lambda: "no-board" in stderr_path.read_text(), "the missing board in the log", GUARD_S)
            process.send_signal(signal.SIGTERM)
            assert process.wait(timeout=GUARD_S) == 0
        finally:
            if process.poll() is None:
                process.kill()
    return stderr_path.read_text()


def test_that_log_lines_carry_journald_priorities_under_systemd(hostd, tmp_path):
    # Fixture: systemd names the stream it connected to stderr as <device>:<inode>
    def stream_of(file) -> str:
        st = os.fstat(file.fileno())
        return f"{st.st_dev}:{st.st_ino}"

    # Act
    journal = run_briefly_with_stderr_in(hostd, tmp_path, tmp_path / "journal.txt", stream_of)
    terminal = run_briefly_with_stderr_in(hostd, tmp_path, tmp_path / "terminal.txt", None)
    redirected = run_briefly_with_stderr_in(hostd, tmp_path, tmp_path / "redirected.txt", "1:1")

    # Assert
    lines = journal.splitlines()
    assert lines and all(re.match(r"^<[0-7]>", line) for line in lines), journal
    priorities = {int(line[1]) for line in lines}
    assert 6 in priorities, journal                                # info
    warnings = [line for line in lines if line.startswith("<4>")]
    assert any("no-board" in line for line in warnings), journal   # the missing board is a warning
    assert not re.search(r"^<\d>\d{4}-\d\d-\d\d", journal, re.M)   # journald stamps the time itself
    for text in (terminal, redirected):                            # not the journal's stream: as ever
        assert not re.search(r"^<\d>", text, re.M), text
        assert re.search(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d{3} (info|warning) ", text, re.M), text


# ---- --version and --print-config -------------------------------------------------------------------

def test_that_cdro_hostd_and_every_python_tool_give_version_protocol_and_layout(hostd):
    # Act
    own = subprocess.run([str(hostd), "--version"], capture_output=True, text=True, timeout=GUARD_S)
    tools = {name: subprocess.run([str(pathlib.Path(sys.executable).parent / name), "--version"], capture_output=True,
                                  text=True, timeout=GUARD_S) for name in PYTHON_TOOLS}

    # Assert
    assert own.returncode == 0, own.stderr
    assert own.stdout.strip() == f"cdro-hostd 0.1.0 {VERSION_TAIL}"
    assert len(tools) >= 11
    for name, result in tools.items():
        assert result.returncode == 0, (name, result.stderr)
        assert result.stdout.strip() == f"{name} 0.1.0 {VERSION_TAIL}", name


def print_config(hostd, *args, cwd=None):
    result = subprocess.run([str(hostd), "--print-config", *map(str, args)], capture_output=True, text=True,
                            timeout=GUARD_S, cwd=cwd)
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_that_print_config_prints_every_section_with_defaults_and_reads_back(hostd, tmp_path):
    # Act
    defaults = print_config(hostd)
    configured = print_config(hostd, "--config", REPO / "config/cdro-hostd.example.yaml", "--device", "/dev/cdro-tag",
                              "--http-port", "8181")
    path = tmp_path / "printed.yaml"
    path.write_text(configured)
    back = print_config(hostd, "--config", path)

    # Assert
    printed = yaml.safe_load(defaults)
    assert list(printed) == ["serial", "nodes", "schedule", "capture", "output", "jsonl", "mqtt", "mqtt_auth", "http",
                             "checkpoint", "odometry", "logging", "web", "engine", "movement", "calibration",
                             "map"]
    assert printed["web"] == {"floor_plan": {"path": "", "metres_per_pixel": 0.05, "origin_x_m": 0,
                                             "origin_y_m": 0, "rotation_rad": 0}}
    assert printed["serial"]["device"] == "/dev/ttyACM0" and printed["serial"]["baud"] == 115200
    assert printed["jsonl"] == {"rotate_mib": 64, "keep": 5, "max_node_rate_hz": 2}
    assert printed["mqtt"]["url"] == "" and printed["mqtt_auth"]["username"] == ""
    assert printed["output"]["jsonl"] == "-" and printed["http"]["port"] == 8080
    assert printed["map"] == {"heights_csv": "", "fixed_csv": "", "moving": []}
    example = yaml.safe_load(configured)
    assert example["serial"]["device"] == "/dev/cdro-tag" and example["http"]["port"] == 8181
    assert example["mqtt"]["url"] == "mqtt://127.0.0.1:1883"
    assert example["nodes"]["ids"] == [0x6069, 0x6A11, 0x6A2C, 0x6A3E, 0x6A4F, 0x6A5B, 0x6A60]
    assert back == configured


# ---- JSON Lines: appended, rotated, rate-limited -----------------------------------------------------

@pytest.fixture(scope="module")
def demo_capture(tmp_path_factory):
    """30 s of the demo scenario from the network simulator (its default seed), as a capture."""
    path = tmp_path_factory.mktemp("jsonl") / "demo.cdrocap"
    subprocess.run([sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo", "--duration", "30",
                    "--capture", str(path)], check=True, capture_output=True, timeout=GUARD_S)
    return path


def replay(hostd, capture, jsonl, tmp_path, config_text=""):
    config = tmp_path / "replay.yaml"
    config.write_text(config_text or "{}\n")
    result = subprocess.run([str(hostd), "--config", str(config), "--replay", str(capture), "--speed", "max",
                             "--jsonl", str(jsonl)], capture_output=True, text=True, timeout=GUARD_S, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    return result


def estimate_lines(path: pathlib.Path) -> list[dict]:
    import json
    return [line for line in map(json.loads, path.read_text().splitlines()) if line.get("type") in ("node", "robot")]


def key_of(line: dict):
    return line.get("id", "robot")


def test_that_json_lines_are_limited_per_node_by_default_and_end_with_the_last_estimate(hostd, demo_capture,
                                                                                       tmp_path):
    # Act
    replay(hostd, demo_capture, tmp_path / "limited.jsonl", tmp_path)
    replay(hostd, demo_capture, tmp_path / "every.jsonl", tmp_path, "jsonl:\n  max_node_rate_hz: 0\n")
    limited, every = estimate_lines(tmp_path / "limited.jsonl"), estimate_lines(tmp_path / "every.jsonl")

    # Assert
    assert every and limited
    assert len(limited) < len(every) / 2, (len(limited), len(every))
    times: dict = {}
    for line in limited:
        times.setdefault(key_of(line), []).append(line["t_s"])
    for key, ts in times.items():
        gaps = [b - a for a, b in zip(ts[:-1], ts[1:-1])]   # the last line is the end of the run's
        assert all(gap >= 0.5 - 1e-6 for gap in gaps), (key, min(gaps))
    last_limited = {key_of(line): line for line in limited}
    last_every = {key_of(line): line for line in every}
    assert last_limited.keys() == last_every.keys()
    for key, line in last_every.items():
        for field in ("x_m", "y_m", "status"):
            if field in line:
                assert last_limited[key][field] == line[field], (key, field)


def test_that_json_lines_are_appended_across_runs_not_truncated(hostd, demo_capture, tmp_path):
    # Fixture
    out = tmp_path / "estimates.jsonl"

    # Act
    replay(hostd, demo_capture, out, tmp_path)
    first = estimate_lines(out)
    replay(hostd, demo_capture, out, tmp_path)
    both = estimate_lines(out)

    # Assert
    assert first and both == first + first


def test_that_the_json_lines_file_is_rotated_by_size_and_keeps_whole_lines(hostd, demo_capture, tmp_path):
    # Fixture
    out = tmp_path / "estimates.jsonl"
    limit_bytes = int(0.01 * 1024 * 1024)

    # Act
    replay(hostd, demo_capture, out, tmp_path, "jsonl:\n  rotate_mib: 0.01\n  keep: 2\n  max_node_rate_hz: 0\n")
    files = [out, out.with_name(out.name + ".1"), out.with_name(out.name + ".2")]

    # Assert
    assert all(f.exists() for f in files), sorted(p.name for p in tmp_path.iterdir())
    assert not out.with_name(out.name + ".3").exists()
    for f in files:
        text = f.read_text()
        assert text.endswith("\n") and 0 < len(text.encode()) <= limit_bytes, (f.name, len(text))
        estimate_lines(f)  # every line is whole JSON


# ---- Prometheus /metrics -------------------------------------------------------------------------------

def http_get(port: int, path: str) -> tuple[str, str]:
    import urllib.request
    with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=10) as response:
        return response.headers.get("Content-Type", ""), response.read().decode()


def test_that_metrics_parse_as_prometheus_text_with_the_counters_and_rates(hostd, demo_capture, tmp_path):
    # Fixture
    import json

    from prometheus_client.parser import text_string_to_metric_families
    port = free_port()
    process = subprocess.Popen([str(hostd), "--replay", str(demo_capture), "--speed", "1", "--jsonl", "",
                                "--http-port", str(port)], cwd=tmp_path, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    try:
        def nodes_on_the_map():
            try:
                return json.loads(http_get(port, "/api/map")[1])["nodes"]
            except OSError:
                return False
        wait_until(nodes_on_the_map, "nodes on the map", GUARD_S)

        # Act
        content_type, text = http_get(port, "/metrics")
        health = json.loads(http_get(port, "/api/health")[1])
    finally:
        process.send_signal(signal.SIGTERM)
        process.wait(timeout=GUARD_S)
    families = {family.name: family for family in text_string_to_metric_families(text)}

    # Assert
    assert content_type.startswith("text/plain; version=0.0.4")
    for family in families.values():
        assert re.fullmatch(r"cdro_[a-z0-9_]+", family.name), family.name
        assert family.documentation, f"{family.name} has no HELP"
        assert family.type in ("counter", "gauge"), family.name
    for name, value in health["counters"].items():
        family = families[f"cdro_{name}"]       # the parser takes _total off a counter's family name
        assert family.type == "counter", name
        (sample,) = family.samples
        assert sample.name == f"cdro_{name}_total"
        assert 0 <= sample.value <= value, name  # the health line was read after the metrics
    assert families["cdro_frames_ok"].samples[0].value > 0
    link = {s.labels["state"]: s.value for s in families["cdro_link_state"].samples}
    assert link["replay"] == 1 and sum(link.values()) == 1
    for rate in ("cdro_frames_per_second", "cdro_ranges_per_second", "cdro_rejects_per_second",
                 "cdro_received_bytes_per_second", "cdro_run_time_seconds"):
        assert families[rate].type == "gauge" and families[rate].samples[0].value >= 0, rate
    (info,) = families["cdro_build_info"].samples
    assert info.labels["frame_layout"] == f"0x{CONSTANTS['CDRO_LAYOUT_HASH']:04X}" and info.value == 1
    nodes = {s.labels["status"]: s.value for s in families["cdro_nodes"].samples}
    assert sum(nodes.values()) > 0


# ---- MQTT with credentials and TLS --------------------------------------------------------------------

class SecureBroker:
    """mosquitto 2 with a password file and a TLS listener on localhost, its certificate
    self-signed for localhost by openssl (started by tests/conftest.py's start_mosquitto)."""

    USER, PASSWORD = "robot", "s3cret-pass"

    def __init__(self, tmp_path: pathlib.Path, start_mosquitto):
        passwd = shutil.which("mosquitto_passwd")
        if passwd is None or shutil.which("openssl") is None:
            pytest.fail("mosquitto, mosquitto_passwd and openssl are needed (scripts/setup.sh installs them)")
        self.dir = tmp_path / "broker"
        self.dir.mkdir()
        self.cert = self.dir / "broker.crt"
        key = self.dir / "broker.key"
        subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj",
                        "/CN=localhost", "-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1",
                        "-keyout", str(key), "-out", str(self.cert)], check=True, capture_output=True, timeout=GUARD_S)
        passwords = self.dir / "passwords"
        subprocess.run([passwd, "-c", "-b", str(passwords), self.USER, self.PASSWORD], check=True,
                       capture_output=True, timeout=GUARD_S)
        self.broker = start_mosquitto(f"allow_anonymous false\npassword_file {passwords}\n"
                                      f"certfile {self.cert}\nkeyfile {key}\n")
        self.port = self.broker.port


@pytest.fixture
def secure_broker(tmp_path, start_mosquitto):
    return SecureBroker(tmp_path, start_mosquitto)


def subscribe_tls(broker: SecureBroker, topics: list[str]):
    """An independent client (paho-mqtt) over TLS with the right credentials; messages by topic."""
    import paho.mqtt.client as mqtt
    received: dict[str, list[str]] = {}
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="test-subscriber")
    client.username_pw_set(broker.USER, broker.PASSWORD)
    client.tls_set(ca_certs=str(broker.cert))
    client.on_connect = lambda c, userdata, flags, rc, props: [c.subscribe(t) for t in topics]
    client.on_message = lambda c, userdata, message: received.setdefault(message.topic, []).append(
        message.payload.decode())
    client.connect("localhost", broker.port)
    client.loop_start()
    return client, received


def mqtt_config(tmp_path, broker: SecureBroker, password: str) -> pathlib.Path:
    secret = tmp_path / f"password-{len(password)}"
    secret.write_text(password + "\n")
    secret.chmod(0o600)
    config = tmp_path / f"mqtt-{len(password)}.yaml"
    config.write_text(f"mqtt:\n  url: mqtts://localhost:{broker.port}\n  client_id: cdro-{len(password)}\n"
                      f"mqtt_auth:\n  username: {broker.USER}\n  password_file: {secret}\n  ca_file: {broker.cert}\n")
    return config


def test_that_the_service_publishes_over_tls_with_username_and_password(hostd, tmp_path, secure_broker):
    # Fixture
    client, received = subscribe_tls(secure_broker, ["cdro/status", "cdro/health"])
    config = mqtt_config(tmp_path, secure_broker, SecureBroker.PASSWORD)
    process = subprocess.Popen([str(hostd), "--config", str(config), *quiet_service_args(tmp_path)], cwd=tmp_path,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        # Act
        wait_until(lambda: "online" in received.get("cdro/status", []) and received.get("cdro/health"),
                   "status and health over TLS", GUARD_S)
        process.send_signal(signal.SIGTERM)
        status = process.wait(timeout=GUARD_S)
        wait_until(lambda: received["cdro/status"][-1] == "offline", "the clean shutdown's offline", GUARD_S)
    finally:
        if process.poll() is None:
            process.kill()
        client.loop_stop()
        client.disconnect()

    # Assert
    stderr = process.stderr.read()
    assert status == 0, stderr
    assert f"mqtt: connected to localhost:{secure_broker.port}" in stderr
    assert not re.search(r"^\S+ \S+ error ", stderr, re.M), stderr


def test_that_a_wrong_password_is_a_clear_error_and_the_service_keeps_running(hostd, tmp_path, secure_broker):
    # Fixture
    config = mqtt_config(tmp_path, secure_broker, "not-the-password")
    port = free_port()
    stderr_path = tmp_path / "stderr.txt"
    with open(stderr_path, "w") as stderr:
        process = subprocess.Popen([str(hostd), "--config", str(config),
                                    *quiet_service_args(tmp_path, **{"--http-port": str(port)})], cwd=tmp_path,
                                   stdout=subprocess.DEVNULL, stderr=stderr)
    try:
        # Act
        wait_until(lambda: "refused the credentials" in stderr_path.read_text(), "the credentials error", GUARD_S)
        time.sleep(1.5)  # a retry or two
        running = process.poll() is None
        _, health = http_get(port, "/api/health")
        process.send_signal(signal.SIGTERM)
        status = process.wait(timeout=GUARD_S)
    finally:
        if process.poll() is None:
            process.kill()

    # Assert
    log = stderr_path.read_text()
    assert running and status == 0, log
    (line,) = [line for line in log.splitlines() if "refused the credentials" in line]  # once, not per retry
    assert " error " in line and "mqtt_auth.username" in line and "mqtt_auth.password_file" in line, line
    assert '"mqtt_connects":0' in health.replace(" ", "")
