"""A hostile-network run for the tests: cdro-sim as the device on a pseudo-terminal, cdro-fault-proxy
in front of it, and a host process (cdro-hostd, or the service's test harness) on the proxy's
pseudo-terminal. The host is given here only a link path; the caller starts it.

    with HostileLink(tmp_path, faults={"phantom": 0.1}, seed=3) as run:
        host = subprocess.Popen([... "--device", str(run.link) ...])
        report = run.finish(bytes_read=lambda: ...)   # the proxy's counts, once the host read all

Every wait is a deadlock guard; nothing depends on how fast the machine is."""
from __future__ import annotations

import json
import pathlib
import subprocess
import sys
import time
from typing import Callable

from ..evaluation.inputs import Policy, read_truth

GUARD_S = 120.0


def wait_until(predicate: Callable[[], object], what: str, timeout_s: float = GUARD_S):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


class HostileLink:
    def __init__(self, folder: pathlib.Path, faults: dict[str, float], seed: int, scenario: str = "demo",
                 duration_s: float = 15.0, speed: float = 4.0, slow: tuple[float, float, float] | None = None):
        self.folder = pathlib.Path(folder)
        self.device = self.folder / "device"
        self.link = self.folder / "faulty"
        self.truth_csv = self.folder / "truth.csv"
        self.heights_csv = self.folder / "heights.csv"
        self.report_path = self.folder / "proxy.json"
        self._sim_log = open(self.folder / "sim.log", "w")
        self._proxy_log = open(self.folder / "proxy.log", "w")
        print(f"hostile link: {scenario} seed {seed}, faults {faults}, {duration_s} simulated s at {speed}x")
        self.sim = subprocess.Popen(
            [sys.executable, "-m", "cdro_tools.sim", "--scenario", scenario, "--seed", str(seed), "--duration",
             str(duration_s), "--pty", str(self.device), "--speed", str(speed), "--no-faults", "--truth-csv",
             str(self.truth_csv), "--heights-csv", str(self.heights_csv)],
            stdout=subprocess.DEVNULL, stderr=self._sim_log)
        proxy = [sys.executable, "-m", "cdro_tools.fault_proxy", "--device", str(self.device), "--link",
                 str(self.link), "--seed", str(seed), "--report", str(self.report_path)]
        for name, rate in faults.items():
            proxy += ["--fault", f"{name}={rate}"]
        if slow is not None:
            proxy += ["--slow-start-s", str(slow[0]), "--slow-window-s", str(slow[1]), "--slow-delay-s", str(slow[2])]
        wait_until(self.device.is_symlink, "the simulator's pseudo-terminal")
        self.proxy = subprocess.Popen(proxy, stdout=subprocess.DEVNULL, stderr=self._proxy_log)
        wait_until(self.link.is_symlink, "the proxy's pseudo-terminal")

    def truth(self) -> dict[int, tuple[float, float]]:
        xy, _ = read_truth(str(self.truth_csv), [], Policy.STRICT)
        return {node_id: (float(p[0]), float(p[1])) for node_id, p in xy.items()}

    def finish(self, bytes_read: Callable[[], int]) -> dict:
        """Waits for the scenario's end and the proxy's report, then until the host has read
        every byte the proxy passed on (bytes_read: the host's bytes_received)."""
        assert self.sim.wait(timeout=GUARD_S) == 0, (self.folder / "sim.log").read_text()
        assert self.proxy.wait(timeout=GUARD_S) == 0, (self.folder / "proxy.log").read_text()
        report = json.loads(self.report_path.read_text())
        wait_until(lambda: bytes_read() >= report["bytes_to_host"], "the host to read every byte")
        return report

    def close(self) -> None:
        for process in (self.proxy, self.sim):
            if process.poll() is None:
                process.terminate()
                try:
                    process.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    process.kill()
        self._sim_log.close()
        self._proxy_log.close()

    def __enter__(self) -> "HostileLink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
