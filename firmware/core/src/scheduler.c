/*
 * scheduler.c: round robin over the pairs with moving boost, retries and backoff (see
 * scheduler.h).
 */
#include "cdro_fw/scheduler.h"

#include <string.h>

#define SKIP_MASK 0x0FU
#define FAILED_SLOTS_SHIFT 4U

void cdro_sched_init(cdro_sched_t *sched)
{
    memset(sched, 0, sizeof(*sched));
    sched->mode = CDRO_SCHEDULE_ALL_PAIRS;
    sched->boost = 2;
    sched->max_retries = 1;
    sched->current = CDRO_SCHED_NO_PAIR;
}

static void restart_round(cdro_sched_t *sched)
{
    sched->pass = 0;
    sched->cursor = 0;
}

void cdro_sched_set_nodes(cdro_sched_t *sched, uint8_t node_count)
{
    sched->node_count = node_count > CDRO_FW_MAX_REMOTE_NODES ? (uint8_t)CDRO_FW_MAX_REMOTE_NODES : node_count;
    memset(sched->pairs, 0, sizeof(sched->pairs));
    sched->current = CDRO_SCHED_NO_PAIR;
    sched->attempts = 0;
    restart_round(sched);
}

uint8_t cdro_sched_pair_count(const cdro_sched_t *sched)
{
    const uint8_t n = sched->node_count;
    if (sched->mode == CDRO_SCHEDULE_ALL_PAIRS && n >= 2U) {
        return (uint8_t)(n + (uint8_t)((uint16_t)n * (uint16_t)(n - 1U) / 2U));
    }
    return n;
}

void cdro_sched_configure(cdro_sched_t *sched, uint8_t mode, uint8_t boost, uint8_t max_retries)
{
    sched->mode = mode;
    sched->boost = boost == 0U ? 1U : boost;
    sched->max_retries = max_retries;
    if (sched->current != CDRO_SCHED_NO_PAIR && sched->current >= cdro_sched_pair_count(sched)) {
        sched->current = CDRO_SCHED_NO_PAIR; /* its pair left the list: the slot ends here */
    }
    if (sched->pass >= sched->boost || sched->cursor >= cdro_sched_pair_count(sched)) {
        restart_round(sched);
    }
}

void cdro_sched_pair_nodes(const cdro_sched_t *sched, uint8_t pair, uint8_t *from, uint8_t *to)
{
    const uint8_t n = sched->node_count;
    uint8_t i = 1;
    uint8_t k;
    if (pair < n) {
        *from = 0;
        *to = (uint8_t)(pair + 1U);
        return;
    }
    k = (uint8_t)(pair - n);
    /* Node i initiates the n - i pairs (Ri, Rj), j > i. */
    while (i < n && k >= (uint8_t)(n - i)) {
        k = (uint8_t)(k - (n - i));
        ++i;
    }
    *from = i;
    *to = (uint8_t)(i + 1U + k);
}

uint8_t cdro_backoff_failed(uint8_t backoff)
{
    uint8_t failed = (uint8_t)(backoff >> FAILED_SLOTS_SHIFT);
    uint8_t skip;
    if (failed < 15U) {
        ++failed;
    }
    skip = (uint8_t)(failed >= 4U ? CDRO_FW_BACKOFF_MAX_ROUNDS : (1U << (failed - 1U)) - 1U);
    if (skip > CDRO_FW_BACKOFF_MAX_ROUNDS) {
        skip = CDRO_FW_BACKOFF_MAX_ROUNDS;
    }
    /* Sitting out s rounds: the rest of this round and the next s rounds, whose starts count
     * the stored s + 1 down to 0. s = 0: no backoff at all. */
    if (skip > 0U) {
        ++skip;
    }
    return (uint8_t)((uint8_t)(failed << FAILED_SLOTS_SHIFT) | skip);
}

uint8_t cdro_backoff_round_start(uint8_t backoff)
{
    return (backoff & SKIP_MASK) != 0U ? (uint8_t)(backoff - 1U) : backoff;
}

static void new_round(cdro_sched_t *sched)
{
    uint8_t p;
    const uint8_t count = cdro_sched_pair_count(sched);
    ++sched->rounds;
    for (p = 0; p < count; ++p) {
        sched->pairs[p].backoff = cdro_backoff_round_start(sched->pairs[p].backoff);
    }
}

uint8_t cdro_sched_next(cdro_sched_t *sched, uint32_t moving_mask, cdro_sched_slot_t *slot)
{
    const uint8_t count = cdro_sched_pair_count(sched);
    uint16_t visits;
    const uint16_t limit = (uint16_t)((uint16_t)sched->boost * count);
    if (sched->current != CDRO_SCHED_NO_PAIR) { /* retries of the slot in progress come first */
        slot->pair = sched->current;
        cdro_sched_pair_nodes(sched, sched->current, &slot->from, &slot->to);
        slot->is_retry = (uint8_t)(sched->attempts > 0U);
        return 1;
    }
    if (count == 0U) {
        return 0;
    }
    for (visits = 0; visits < limit; ++visits) {
        uint8_t p;
        uint8_t from;
        uint8_t to;
        if (sched->cursor >= count) {
            sched->cursor = 0;
            if (++sched->pass >= sched->boost) {
                sched->pass = 0;
                new_round(sched);
            }
        }
        p = sched->cursor++;
        if ((sched->pairs[p].backoff & SKIP_MASK) != 0U) {
            continue; /* backing off this round */
        }
        if ((uint8_t)(p % sched->boost) != sched->pass) {
            if (moving_mask == 0U) {
                continue;
            }
            cdro_sched_pair_nodes(sched, p, &from, &to);
            if (((moving_mask >> from) & 1UL) == 0U && ((moving_mask >> to) & 1UL) == 0U) {
                continue; /* a still pair's visit is in another pass */
            }
        } else {
            cdro_sched_pair_nodes(sched, p, &from, &to);
        }
        sched->current = p;
        sched->attempts = 0;
        slot->pair = p;
        slot->from = from;
        slot->to = to;
        slot->is_retry = 0;
        return 1;
    }
    return 0;
}

uint8_t cdro_sched_report(cdro_sched_t *sched, uint8_t success)
{
    cdro_pair_state_t *state;
    uint8_t actions = 0;
    if (sched->current == CDRO_SCHED_NO_PAIR) {
        return 0;
    }
    state = &sched->pairs[sched->current];
    if (sched->attempts < 255U) {
        ++sched->attempts;
    }
    if (success) {
        state->failed_attempts = 0;
        state->backoff = 0;
        sched->current = CDRO_SCHED_NO_PAIR;
        return 0;
    }
    if (state->failed_attempts < 255U) {
        ++state->failed_attempts;
        if (state->failed_attempts == CDRO_FW_RANGING_ERROR_STREAK) {
            actions |= CDRO_SCHED_STREAK_ERROR;
        }
    }
    if (sched->attempts <= sched->max_retries) {
        actions |= CDRO_SCHED_RETRY;
    } else {
        state->backoff = cdro_backoff_failed(state->backoff);
        sched->current = CDRO_SCHED_NO_PAIR;
    }
    return actions;
}
