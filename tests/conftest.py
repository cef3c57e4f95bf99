"""Shared pytest fixtures: where the golden vectors, the native build and the AVR build live, and a real MQTT
broker (mosquitto) for the tests that need one."""
import os
import pathlib
import shutil
import socket
import subprocess
import time

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def repo_root() -> pathlib.Path:
    return REPO


@pytest.fixture(scope="session")
def golden_dir() -> pathlib.Path:
    return REPO / "tests" / "golden"


@pytest.fixture(scope="session")
def build_dir() -> pathlib.Path:
    """The native CMake build (scripts/test.sh sets CDRO_BUILD_DIR; default ./build)."""
    return pathlib.Path(os.environ.get("CDRO_BUILD_DIR", REPO / "build"))


@pytest.fixture(scope="session")
def avr_build_dir() -> pathlib.Path:
    """The Uno's AVR build (scripts/test.sh sets CDRO_AVR_BUILD_DIR; default ./build-avr)."""
    return pathlib.Path(os.environ.get("CDRO_AVR_BUILD_DIR", REPO / "build-avr"))


@pytest.fixture(scope="session")
def hostd(build_dir) -> pathlib.Path:
    """The cdro-hostd of the native build."""
    binary = build_dir / "bin" / "cdro-hostd"
    assert binary.is_file(), f"{binary} not found: build first (scripts/test.sh), or set CDRO_BUILD_DIR"
    return binary


@pytest.fixture(scope="session")
def fil_binary(build_dir) -> pathlib.Path:
    """The cdro-fil of the native build."""
    binary = build_dir / "bin" / "cdro-fil"
    assert binary.is_file(), f"{binary} not found: build first (scripts/test.sh), or set CDRO_BUILD_DIR"
    return binary


# ---- a real MQTT broker -------------------------------------------------------------------------

MOSQUITTO_GUARD_S = 60.0  # s; reached only when something is broken
MOSQUITTO_BROKERS = pytest.StashKey[list]()  # the brokers a test started, for its report


class Mosquitto:
    """A real mosquitto on a free loopback port, its config file and its log in `directory`; once
    constructed it accepts connections. `settings` are the config's lines besides the listener
    (per_listener_settings stays off, so they all apply to it: TLS files, a password file...)."""

    host = "127.0.0.1"

    def __init__(self, directory: pathlib.Path, name: str, settings: str):
        binary = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
        if not os.path.exists(binary):
            pytest.fail("mosquitto is not installed (scripts/setup.sh installs it)")
        with socket.socket() as s:
            s.bind((self.host, 0))
            self.port = s.getsockname()[1]
        self.config_path = directory / f"{name}.conf"
        self.log_path = directory / f"{name}.log"
        # user root: run as root, mosquitto would become user mosquitto, who cannot read the test's
        # files (a TLS key, a password file); not run as root, the line has no effect.
        self.config_path.write_text(f"user root\npersistence false\nlistener {self.port} {self.host}\n{settings}")
        with open(self.log_path, "w") as log:  # mosquitto logs to stderr
            self.process = subprocess.Popen([binary, "-c", str(self.config_path)], stdout=log,
                                            stderr=subprocess.STDOUT)
        deadline = time.monotonic() + MOSQUITTO_GUARD_S
        while not self._accepting():
            if self.process.poll() is not None or time.monotonic() > deadline:
                self.stop()
                pytest.fail(f"mosquitto did not start listening on {self.host}:{self.port} "
                            f"({self.config_path}):\n{self.log()}")
            time.sleep(0.02)

    def _accepting(self) -> bool:
        try:
            with socket.create_connection((self.host, self.port), timeout=1):
                return True
        except OSError:
            return False

    def log(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=MOSQUITTO_GUARD_S)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


@pytest.fixture
def start_mosquitto(request, tmp_path):
    """start_mosquitto(settings) starts a Mosquitto with those config lines (by default anonymous
    clients allowed), its files in tmp_path; each is stopped after the test, and when the test
    fails its log is in the report."""
    brokers: list[Mosquitto] = []
    request.node.stash[MOSQUITTO_BROKERS] = brokers

    def start(settings: str = "allow_anonymous true\n") -> Mosquitto:
        name = "mosquitto" if not brokers else f"mosquitto-{len(brokers) + 1}"
        broker = Mosquitto(tmp_path, name, settings)
        brokers.append(broker)
        return broker

    yield start
    for broker in brokers:
        broker.stop()


@pytest.fixture
def mosquitto(start_mosquitto) -> Mosquitto:
    """A real mosquitto on a free loopback port, anonymous clients allowed: .host, .port."""
    return start_mosquitto()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    if report.failed:
        for broker in item.stash.get(MOSQUITTO_BROKERS, []):
            report.sections.append((f"{broker.log_path.name} ({broker.host}:{broker.port})", broker.log()))
    return report
