"""The service on a hostile link, without the engine so that it
runs under ASan/UBSan too (tests/service is run again against the sanitized build): cdro-sim
plays the device, the seeded cdro-fault-proxy mixes every fault class into its frames, and the
service's counters must say exactly what was injected. tests/hostd/test_hostile_network.py runs
each class alone against cdro-hostd and bounds the map as well.

The seed is printed (CDRO_TEST_SEED replays one). Every wait is a deadlock guard."""
from __future__ import annotations

import os

from cdro_tools.simulation.hostile import HostileLink
from service_support import Harness

MIXED = {"bit_flip": 0.04, "garbage": 0.04, "phantom": 0.04, "version": 0.04, "duplicate": 0.04, "drop": 0.04}
EXACT = ("chunks_rejected", "version_errors", "frames_rejected_unknown_node", "unknown_node_frames",
         "nodes_learned", "duplicate_frames", "device_resets", "frames_dropped_incompatible",
         "incompatible_devices", "frames_lost")


def test_every_fault_of_a_mixed_run_is_counted_exactly(build_dir, tmp_path):
    seed = int(os.environ.get("CDRO_TEST_SEED", "5"))
    with HostileLink(tmp_path, MIXED, seed=seed, duration_s=20.0, speed=4.0) as run:
        harness = Harness(build_dir, tmp_path, device=run.link, nodes=[], name="service")
        try:
            report = run.finish(lambda: (harness.health() or {"counters": {"bytes_received": 0}})["counters"]
                                ["bytes_received"])
            assert harness.stop() == 0, harness.log()
        finally:
            if harness.process.poll() is None:
                harness.process.kill()
    counters = [line for line in harness.jsonl_lines() if line["type"] == "health"][-1]["counters"]
    print(f"injected {report['injected']} into {report['frames_in']} frames")
    assert all(report["injected"][name] > 0 for name in MIXED), report["injected"]
    for counter in EXACT:
        assert counters[counter] == report["expected_counters"][counter], (
            f"{counter}: {counters[counter]} counted, {report['expected_counters'][counter]} expected")
    # Only the network's nodes reached the consumer: no phantom.
    named = {line[key] for line in harness.received_lines() if line["kind"] == "range" for key in ("from", "to")}
    assert named <= {0x6001 + i for i in range(7)}, sorted(hex(n) for n in named)
