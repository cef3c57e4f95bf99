/*
 * scheduler.h: which pair ranges in the next slot (docs/protocol.md, "Schedule", and
 * docs/firmware.md for the exact rules of retries and backoff).
 *
 * Nodes are indices: 0 is the own node O, 1..n the remote nodes R1..Rn in list order. Pairs
 * are indices too: pair p < n is the direct pair (O, R(p+1)); in ALL_PAIRS mode the pairs
 * n, n+1, ... are the remote pairs (Ri, Rj), i < j, in the order (R1,R2), (R1,R3), ...,
 * (R1,Rn), (R2,R3), ... The index of a pair does not depend on the mode, so per-pair state
 * survives a mode change.
 *
 * A round is `boost` passes over the pair list. In pass k a pair is visited if either end is
 * flagged moving, or if p mod boost == k: every pair once per round, pairs with a moving end
 * `boost` times, spread evenly. A visit is one slot: the first attempt, then up to
 * max_retries immediate retries while it fails. A pair whose slot failed n times in a row sits
 * out the rest of the round and then s = min(2^(n-1) - 1, CDRO_FW_BACKOFF_MAX_ROUNDS) whole
 * rounds (s = 0, 1, 3, 4, 4, ...; s = 0 means no backoff); success resets it. So no pair goes
 * more than CDRO_FW_BACKOFF_MAX_ROUNDS whole rounds without an attempt. Pure logic: no clock,
 * no I/O.
 */
#ifndef CDRO_FW_SCHEDULER_H
#define CDRO_FW_SCHEDULER_H

#include <stdint.h>

#include "cdro_fw/config.h"

#ifdef __cplusplus
extern "C" {
#endif

#define CDRO_SCHED_NO_PAIR 0xFFU

typedef struct cdro_pair_state {
    uint8_t failed_attempts; /* consecutive failed attempts, saturating at 255 */
    uint8_t backoff;         /* high nibble: consecutive failed slots (<= 15); low: round starts to sit out */
} cdro_pair_state_t;

typedef struct cdro_sched {
    uint8_t node_count;  /* remote nodes n */
    uint8_t mode;        /* CDRO_SCHEDULE_* */
    uint8_t boost;       /* passes per round, 1..8 */
    uint8_t max_retries; /* 0..10 */
    uint8_t pass;        /* current pass, 0..boost-1 */
    uint8_t cursor;      /* next pair to consider in this pass */
    uint8_t current;     /* pair of the slot in progress, or CDRO_SCHED_NO_PAIR */
    uint8_t attempts;    /* attempts made in the slot in progress */
    uint32_t rounds;     /* rounds completed (for tests and diagnostics) */
    cdro_pair_state_t pairs[CDRO_FW_MAX_PAIRS];
} cdro_sched_t;

typedef struct cdro_sched_slot {
    uint8_t pair;     /* pair index */
    uint8_t from;     /* node index of the ranging node (0 = own node) */
    uint8_t to;       /* node index of the partner */
    uint8_t is_retry; /* 1 if a previous attempt of this slot failed */
} cdro_sched_slot_t;

/* What cdro_sched_report tells the caller to do. */
#define CDRO_SCHED_RETRY 0x01        /* the slot goes on: attempt the same pair again now */
#define CDRO_SCHED_STREAK_ERROR 0x02 /* this failure completed a streak: send ERROR RANGING */

/* Defaults of docs/protocol.md: ALL_PAIRS, boost 2, max_retries 1; no nodes. */
void cdro_sched_init(cdro_sched_t *sched);

/* A new node list: forgets all per-pair state and restarts from the first pair. */
void cdro_sched_set_nodes(cdro_sched_t *sched, uint8_t node_count);

/* New parameters, effective at the next slot (a slot in progress ends first). The round
 * restarts if the pass or cursor no longer fits; per-pair state is kept. */
void cdro_sched_configure(cdro_sched_t *sched, uint8_t mode, uint8_t boost, uint8_t max_retries);

uint8_t cdro_sched_pair_count(const cdro_sched_t *sched);

/* Node indices of a pair (from ranges, to responds). */
void cdro_sched_pair_nodes(const cdro_sched_t *sched, uint8_t pair, uint8_t *from, uint8_t *to);

/* The next attempt. moving_mask has bit i set when node i is flagged moving. Returns 0 when
 * there is nothing to range (no pairs); otherwise fills *slot. Visits at most one round of
 * pairs (boost x pairs) per call, so it is bounded even when every pair sits out. */
uint8_t cdro_sched_next(cdro_sched_t *sched, uint32_t moving_mask, cdro_sched_slot_t *slot);

/* The outcome of the attempt returned by the last cdro_sched_next. Returns CDRO_SCHED_* bits. */
uint8_t cdro_sched_report(cdro_sched_t *sched, uint8_t success);

/* The backoff rule on one byte (high nibble: failures in a row; low: round starts to sit out),
 * shared with the accelerometer polls: after a failure, and at each round start. */
uint8_t cdro_backoff_failed(uint8_t backoff);
uint8_t cdro_backoff_round_start(uint8_t backoff);
#define CDRO_BACKOFF_SITTING_OUT(backoff) (((backoff)&0x0FU) != 0U)

#ifdef __cplusplus
}
#endif

#endif /* CDRO_FW_SCHEDULER_H */
