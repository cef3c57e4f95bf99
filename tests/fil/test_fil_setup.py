"""The Pozyx set-up on the unmodified Uno image: cdro-pozyx drives the firmware in
simavr (cdro-fil, tests/fil/bench_setup.yaml, the real device's behaviour) through the bench
checklist (DIAGNOSE), a move of every node to other UWB settings (SET_UWB) and a read-back; the
run's summary then has the stack's worst case over all of it, which must leave 256 B free.
"""
from __future__ import annotations

import json
import pathlib
import signal
import subprocess
import sys
import time

import pytest

from fil_support import avr_elf

HERE = pathlib.Path(__file__).resolve().parent
SCENARIO = HERE / "bench_setup.yaml"
STACK_HEADROOM_B = 256   # at least this much RAM never touched by the stack
GUARD_S = 60.0           # s of wall-clock time per step; only reached when something is broken


def pozyx(link: pathlib.Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cdro_tools.pozyx", "--device", str(link), "--hello-wait-s", "1.5",
                           *args], capture_output=True, text=True, timeout=GUARD_S)


@pytest.fixture(scope="module")
def bench(build_dir, avr_build_dir, tmp_path_factory):
    binary = build_dir / "bin" / "cdro-fil"
    elf = avr_elf(avr_build_dir)
    for path in (binary, elf):
        if not path.exists():
            pytest.fail(f"{path} missing: build the native tree and the AVR image first")
    directory = tmp_path_factory.mktemp("fil-setup")
    link = directory / "tty"
    summary = directory / "summary.json"
    log = open(directory / "fil.log", "w")
    fil = subprocess.Popen([str(binary), "--elf", str(elf), "--scenario", str(SCENARIO), "--link", str(link),
                            "--start-on-open", "--summary", str(summary)], stdout=subprocess.DEVNULL, stderr=log)
    deadline = time.monotonic() + 10.0
    while not link.is_symlink():
        assert fil.poll() is None and time.monotonic() < deadline, (directory / "fil.log").read_text()
        time.sleep(0.01)
    results = {"diagnose": pozyx(link, "diagnose"),
               "uwb": pozyx(link, "uwb", "--channel", "2", "--bitrate", "6.8M", "--prf", "16", "--preamble", "256",
                            "--gain-db", "20", "--protocol", "fast"),
               "info": pozyx(link, "info")}
    fil.send_signal(signal.SIGTERM)
    assert fil.wait(timeout=GUARD_S) == 0, (directory / "fil.log").read_text()
    log.close()
    results["summary"] = json.loads(summary.read_text())
    for name in ("diagnose", "uwb", "info"):
        print(f"--- cdro-pozyx {name} (exit {results[name].returncode})\n{results[name].stdout}{results[name].stderr}")
    return results


def test_diagnose_prints_every_bench_item_from_the_real_image(bench):
    run = bench["diagnose"]
    assert run.returncode == 0, run.stdout + run.stderr
    lines = run.stdout.splitlines()
    assert lines[0].startswith("HELLO: CDRO firmware 1.0, protocol 2, node 0x6000, Pozyx firmware 1.1, found at try 1")
    items = [line for line in lines if line[:2] in {f"{i} " for i in range(1, 8)}]
    assert [int(line.split()[0]) for line in items] == [1, 2, 3, 4, 5, 6, 7, 7], items  # two tags: two item 7s
    by = {int(line.split()[0]): line for line in items}
    to_ack = int(by[1].split("acknowledgement ")[1].split("(")[1].split(")")[0], 16)
    assert to_ack & 0x18 == 0x18, by[1]   # RX_DATA and FUNC: the model's replies raise both
    assert "2 result message from 0x6A01: 4 bytes" in by[2]
    assert "offset honoured" in by[5]
    assert "norm 10" in by[7] or "norm 99" in by[7], by[7]               # ~1000 mg at rest
    assert "failed" not in run.stdout


def test_set_uwb_moves_every_node_and_the_read_back_agrees(bench):
    for name in ("uwb", "info"):
        run = bench[name]
        assert run.returncode == 0, run.stdout + run.stderr
        nodes = [line for line in run.stdout.splitlines() if line.startswith("node 0x")]
        assert [line.split(":")[0] for line in nodes] == ["node 0x6000", "node 0x6A01", "node 0x6A02", "node 0x6B03"]
        for line in nodes:
            assert "channel 2, 6.8Mbit/s, PRF 16 MHz, preamble 256, gain 20.0 dB, fast" in line, line
            assert "differs" not in line
    assert "found at try 1" in bench["info"].stdout, "no reset on reopening: HELLO_REQUEST answered"


def test_the_stack_leaves_at_least_256_bytes_over_all_of_it(bench):
    s = bench["summary"]
    stack = s["stack"]
    print(f"stack: deepest {stack['deepest_bytes']} B, headroom {stack['headroom_bytes']} B "
          f"(painted, never touched: {stack['painted_free_bytes']} B), static data ends at {stack['static_end']:#x}")
    assert s["protocol_violations"] == 0 and s["avr_resets"] == 0
    assert stack["headroom_bytes"] >= STACK_HEADROOM_B
    assert stack["painted_free_bytes"] >= STACK_HEADROOM_B
    # Nothing wrote below the lowest stack pointer; a frame reserved but not written in full
    # (a local buffer) leaves painted bytes under it, so the firmware's own figure (STATUS
    # free_ram_bytes, the painted count) can only be the larger one.
    assert stack["painted_free_bytes"] >= stack["headroom_bytes"]
