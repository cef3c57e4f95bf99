"""cdro-hostd run offline as a user runs it, and the seeds of randomised cases. Shared by the
offline tests (test_offline_cli.py, test_offline_moving.py)."""
from __future__ import annotations

import os
import subprocess

GUARD_S = 60  # s, a deadlock guard only


def run(hostd, *args):
    """cdro-hostd with these arguments; its exit status, stdout and stderr."""
    return subprocess.run([str(hostd), *map(str, args)], capture_output=True, text=True, timeout=GUARD_S)


def seed_of(default):
    """CDRO_TEST_SEED when set, else `default`; printed, so a failure names the seed to replay."""
    seed = int(os.environ.get("CDRO_TEST_SEED", str(default)), 0)
    print(f"seed {seed} (set CDRO_TEST_SEED={seed} to replay)")
    return seed
