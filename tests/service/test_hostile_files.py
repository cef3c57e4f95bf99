"""Files that cannot be hijacked, on the real processes: a link planted where the
service writes its JSON Lines or its checkpoint's temporary file, a world-writable output
directory (docs/service.md, "Security model"; cdro-hostd's offline CSV outputs:
tests/hostd/test_offline_hostile_input.py).
"""
from __future__ import annotations

from service_support import Harness, NODES, OWN, start_running

PRECIOUS = "precious\n"


def plant(tmp_path, name):
    victim = tmp_path / f"victim-{name}"
    victim.write_text(PRECIOUS)
    (tmp_path / name).symlink_to(victim)
    return victim


def test_a_linked_jsonl_output_is_refused_and_its_target_kept(build_dir, tmp_path):
    victim = plant(tmp_path, "run.jsonl")    # the harness writes its JSON Lines to tmp_path/run.jsonl
    harness = Harness(build_dir, tmp_path)
    assert harness.wait_exit() == 2
    assert "symbolic link" in harness.log() and "output.jsonl" in harness.log(), harness.log()
    assert victim.read_text() == PRECIOUS


def test_a_planted_checkpoint_temporary_is_never_written_through(build_dir, tmp_path):
    victim = plant(tmp_path, "run.cdrosog.tmp")
    device, harness = start_running(build_dir, tmp_path)
    for i in range(10):
        device.range_frame(OWN, NODES[i % 3], 3000 + i)
    harness.wait_health(lambda h: h["counters"]["checkpoints_written"] >= 2, "two periodic checkpoints")
    assert harness.stop() == 0, harness.log()
    device.vanish()
    assert victim.read_text() == PRECIOUS
    assert harness.checkpoint.stat().st_size > 0
    assert not list(tmp_path.glob("run.cdrosog.tmp.*")), "a temporary file was left behind"


def test_a_world_writable_output_directory_is_refused(build_dir, tmp_path):
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o1777)
    harness = Harness(build_dir, shared)     # every output of the harness in that directory
    assert harness.wait_exit() == 2
    log = harness.log()
    assert "can be written by every user" in log and str(shared) in log, log
    # Nothing of the service (the harness records what it received itself, before the start).
    assert sorted(p.name for p in shared.iterdir()) == ["run.received.jsonl", "run.stderr.log", "run.yaml"]
