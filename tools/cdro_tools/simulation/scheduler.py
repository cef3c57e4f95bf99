"""The ranging schedule of docs/protocol.md ("Schedule"), as firmware/core/src/scheduler.c keeps it:
the pair list, rounds of `moving_boost` passes, failure streaks and backoff.

- Pairs, by position: (O, R1) .. (O, Rn) in node list order, then in ALL_PAIRS mode (Ri, Rj),
  i < j, in lexicographic order.
- A round is `moving_boost` passes over the pair list; in pass k the pair at position p is
  visited if one of its ends is flagged moving, or if p mod boost = k.
- A pair whose slot failed n times in a row sits out min(2^(n-1) - 1, 4) further rounds and,
  when that is not 0, the rest of that round; a success resets n (and the attempt streak).
- The attempt streak of a pair (failed attempts in a row, retries included) reports ERROR
  RANGING once, at its 5th attempt.
"""
from __future__ import annotations

import dataclasses
from typing import Callable

from ..codec import CONSTANTS as C

BACKOFF_MAX_ROUNDS = 4        # no pair goes more than this many whole rounds without an attempt
FAILURE_STREAK = 5            # consecutive failed attempts of one pair before ERROR RANGING


def backoff_rounds(failed_slots: int) -> int:
    """Whole rounds a pair sits out after its n-th failed slot in a row: 0, 1, 3, 4, 4, ..."""
    return min(2 ** (failed_slots - 1) - 1, BACKOFF_MAX_ROUNDS) if failed_slots > 0 else 0


@dataclasses.dataclass
class PairState:
    failed_slots: int = 0         # slots in a row whose every attempt failed
    failed_attempts: int = 0      # attempts in a row that failed (the ERROR RANGING streak)
    sitting_out: int = 0          # round starts still to come before the pair is visited again


class Scheduler:
    def __init__(self) -> None:
        self.mode = C["CDRO_SCHEDULE_ALL_PAIRS"]
        self.boost = 2
        self.own_id = 0
        self.nodes: list[int] = []
        self.states: list[PairState] = []
        self.pass_ = 0
        self.cursor = 0
        self.rounds = 0

    def pairs(self) -> list[tuple[int, int]]:
        pairs = [(self.own_id, r) for r in self.nodes]
        if self.mode == C["CDRO_SCHEDULE_ALL_PAIRS"]:
            pairs += [(a, b) for i, a in enumerate(self.nodes) for b in self.nodes[i + 1:]]
        return pairs

    def _restart_round(self) -> None:
        self.pass_ = 0
        self.cursor = 0

    def set_nodes(self, own_id: int, nodes: list[int]) -> None:
        """A new node list: every pair's state cleared, the round restarts at its first pair."""
        self.own_id = own_id
        self.nodes = list(nodes)
        n = len(self.nodes)
        self.states = [PairState() for _ in range(n + n * (n - 1) // 2)]   # room for ALL_PAIRS
        self._restart_round()

    def configure(self, mode: int, boost: int) -> None:
        """SET_SCHEDULE: pair states are kept; the round goes on unless it no longer fits."""
        self.mode = mode
        self.boost = max(1, boost)
        if self.pass_ >= self.boost or self.cursor >= len(self.pairs()):
            self._restart_round()

    def _new_round(self, count: int) -> None:
        self.rounds += 1
        for state in self.states[:count]:
            if state.sitting_out:
                state.sitting_out -= 1

    def next(self, moving: Callable[[int], bool]) -> int | None:
        """Position of the next pair to range (None without pairs). Rounds in which every pair is
        backing off pass without taking time, as the firmware's scheduler skips them."""
        pairs = self.pairs()
        count = len(pairs)
        for _ in range(self.boost * count * (BACKOFF_MAX_ROUNDS + 2)):
            if self.cursor >= count:
                self.cursor = 0
                self.pass_ += 1
                if self.pass_ >= self.boost:
                    self.pass_ = 0
                    self._new_round(count)
            p = self.cursor
            self.cursor += 1
            if self.states[p].sitting_out:
                continue
            a, b = pairs[p]
            if p % self.boost != self.pass_ and not (moving(a) or moving(b)):
                continue                     # a still pair's visit is in another pass
            return p
        return None

    def attempt_failed(self, p: int) -> bool:
        """Counts a failed attempt; True when it completes a streak that ERROR RANGING reports."""
        state = self.states[p]
        state.failed_attempts += 1
        return state.failed_attempts == FAILURE_STREAK

    def slot_done(self, p: int, ok: bool) -> None:
        state = self.states[p]
        if ok:
            state.failed_slots = state.failed_attempts = state.sitting_out = 0
        else:
            state.failed_slots += 1
            # the further rounds and, if any, the rest of this round (the next round start
            # counts it off); after one failed slot (0 further rounds) the pair stays in
            further = backoff_rounds(state.failed_slots)
            state.sitting_out = further + 1 if further else 0
