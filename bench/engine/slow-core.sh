#!/usr/bin/env bash
# slow-core.sh: runs a command on one core of this machine held to a share of its time, as a
# stand-in for a computer that many times slower (a Raspberry Pi-class board next to the robot).
#
#   bench/engine/slow-core.sh [--cpu N] [--quota-percent P] -- COMMAND [ARGS...]
#
# The command and every thread it starts run pinned to core N (taskset; default 0) inside a CPU
# control group whose quota is P % of one core (default 25: a core four times slower, on
# average). The quota is the kernel's CFS bandwidth control: within each 100 ms period the group
# runs at this core's full speed for P ms and then waits, so a slow machine's average speed is
# reproduced but not its smoothness: a call that needs more than P ms of CPU is also held up by
# the waits (up to 100 - P ms each period). The script prints how often the group was held
# (cpu.stat) when the command ends, and removes the group. It needs root and a writable cgroup
# file system (v2 with the cpu controller, or v1's cpu hierarchy); it says so and stops when
# there is none. Benchmarks only, run on purpose (docs/bench.md); never a test.
set -euo pipefail

cpu=0
quota_percent=25
while [[ $# -gt 0 ]]; do
    case "$1" in
    --cpu) cpu="$2"; shift 2 ;;
    --quota-percent) quota_percent="$2"; shift 2 ;;
    --) shift; break ;;
    -h | --help) sed -n '2,16p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "slow-core.sh: unknown option $1 (the command goes after --)" >&2; exit 2 ;;
    esac
done
if [[ $# -eq 0 ]]; then
    echo "slow-core.sh: no command (bench/engine/slow-core.sh [--cpu N] [--quota-percent P] -- COMMAND)" >&2
    exit 2
fi
if ! [[ "$quota_percent" =~ ^[0-9]+$ ]] || ((quota_percent < 1 || quota_percent > 100)); then
    echo "slow-core.sh: --quota-percent must be 1..100, not $quota_percent" >&2
    exit 2
fi
period_us=100000
quota_us=$((period_us * quota_percent / 100))
name="cdro-slow-core-$$"

if [[ -f /sys/fs/cgroup/cgroup.controllers ]] && grep -qw cpu /sys/fs/cgroup/cgroup.controllers; then
    group="/sys/fs/cgroup/$name" # cgroup v2, the unified hierarchy at the root
    limit() { echo "$quota_us $period_us" >"$group/cpu.max"; }
elif [[ -d /sys/fs/cgroup/cpu && -w /sys/fs/cgroup/cpu ]]; then
    group="/sys/fs/cgroup/cpu/$name" # cgroup v1's cpu controller
    limit() { echo "$period_us" >"$group/cpu.cfs_period_us" && echo "$quota_us" >"$group/cpu.cfs_quota_us"; }
else
    echo "slow-core.sh: no writable CPU control group here (needs root and cgroup v2 with the cpu controller," \
        "or v1's /sys/fs/cgroup/cpu); nothing was run" >&2
    exit 3
fi
if ! mkdir "$group" 2>/dev/null; then
    echo "slow-core.sh: cannot create $group (root needed); nothing was run" >&2
    exit 3
fi
cleanup() { rmdir "$group" 2>/dev/null || true; }
trap cleanup EXIT
limit
echo "slow-core.sh: core $cpu at $quota_percent % ($quota_us us of every $period_us us), group $group" >&2

status=0
# The child joins the group before it execs the command, so everything it starts is held too.
bash -c 'echo $$ >"$1/cgroup.procs" && shift && exec taskset -c "$@"' _ "$group" "$cpu" "$@" || status=$?

echo "slow-core.sh: the command ended with status $status; the group's cpu.stat:" >&2
sed 's/^/  /' "$group/cpu.stat" >&2
exit "$status"
