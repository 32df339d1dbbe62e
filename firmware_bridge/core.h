/* core.h - the bridge's portable core: protocol handling, tick queue, step generator, counters,
 * inputs and watchdog. No allocation, no board dependency beyond board.h. Portable C99.
 *
 * Use: sb_init(); feed received bytes with sb_rx(); call sb_poll(now) at least by
 * sb_next_deadline() and whenever an input may have changed.
 */
#ifndef SB_CORE_H
#define SB_CORE_H

#include <stdint.h>

#include "proto.h"

#define SB_QUEUE_MAX 4

#define SB_FW_VERSION "0.1.0"

/* states */
#define SB_S_IDLE 0       /* not armed (after power-up or END): no stepping, no watchdog */
#define SB_S_ARMED 1      /* after RESET: waiting for the queue to hold `prime` ticks */
#define SB_S_RUNNING 2
#define SB_S_DRAINING 3   /* after END: runs out the queue, then IDLE */
#define SB_S_FAULT 4      /* latched: nothing moves until RESET */

/* fault bits (latched) */
#define SB_F_WATCHDOG 0x01
#define SB_F_ESTOP 0x02
#define SB_F_ALARM 0x04
#define SB_F_PROTOCOL 0x08
#define SB_F_OVERSPEED 0x10
#define SB_F_HOST_STOP 0x20
#define SB_F_LATE 0x40        /* the board fell behind its step schedule (it cannot time that many steps) */

/* why a STATUS was sent (its last-but-one byte) */
#define SB_WHY_TICK 0     /* at a tick start: the counters hold exactly the ticks before it */
#define SB_WHY_OTHER 1    /* fault, idle period, request: the counters may include part of a tick */

struct sb_tick {
    uint32_t index;
    int16_t pulses[SB_NAXES];
};

struct sb_axis {
    /* current tick */
    uint32_t n;          /* pulses this tick */
    uint32_t k;          /* rising edges emitted */
    uint64_t t_first;    /* tick start + dir set-up (if the direction changed) */
    uint32_t s;          /* span the pulses are spread over, ns (< tick_ns <= 1e8: 32 bits) */
    uint32_t a;          /* offset of the next rising edge from t_first, ns (Bresenham) */
    uint32_t e, q, r;    /* Bresenham remainder (< 2n), quotient and remainder per step */
    uint64_t fall;       /* pending falling edge time, 0 = none */
    uint64_t next;       /* time of this axis's next edge in the current tick, UINT64_MAX = none */
    int8_t dir;          /* +1 / -1 last direction output */
    int8_t sign;         /* this tick's direction */
};

struct sb_config {
    uint32_t tick_ns;
    uint32_t step_width_ns;
    uint32_t dir_setup_ns;
    uint32_t watchdog_us;
    uint8_t queue;       /* ticks the queue may hold, 2..SB_QUEUE_MAX */
    uint8_t prime;       /* ticks queued before stepping starts, 1..queue */
};

struct sb_core {
    struct sb_config cfg;
    struct sb_parser parser;
    uint8_t state;
    uint16_t faults;
    uint8_t expect_seq;           /* next host SEQ */
    uint8_t last_code;
    /* queue */
    struct sb_tick q[SB_QUEUE_MAX];
    uint8_t q_head, q_n;
    /* current tick */
    int cur_active;
    uint32_t cur_index;
    uint64_t cur_start;
    struct sb_axis ax[SB_NAXES];
    uint64_t next_edge;           /* the earliest ax[].next (valid while cur_active) */
    int32_t counters[SB_NAXES];
    int32_t not_executed[SB_NAXES];
    uint32_t dropped_ticks;
    uint32_t started, done;
    uint32_t next_tick;           /* next tick index accepted */
    uint16_t underruns;
    uint16_t inputs;
    uint64_t now;
    uint64_t last_tick_rx;        /* time of the last valid tick (or RESET) */
    uint64_t fault_time;
    uint32_t status_every;        /* a STATUS at every n-th tick start */
    /* home-switch latch (sb_home_edge): per axis the counter at the last switch transition, the
     * number of transitions (mod 256) and the level it went to (bit per axis) */
    int32_t home_latch[SB_NAXES];
    uint8_t home_edges[SB_NAXES];
    uint8_t home_level;
    uint64_t next_idle_status;
    uint64_t watchdog_ns;         /* cfg.watchdog_us x 1000, kept with cfg */
};

void sb_init(struct sb_core *c, uint64_t now_ns);
void sb_rx(struct sb_core *c, const uint8_t *buf, uint32_t n, uint64_t now_ns);
void sb_poll(struct sb_core *c, uint64_t now_ns);
/* The latest time by which sb_poll must run again (tick boundary, watchdog, idle status). */
uint64_t sb_next_deadline(const struct sb_core *c);
/* The time of the next step edge of the current tick (UINT64_MAX if none): a board that writes its
 * pins when sb_poll passes an edge's time wakes up by then (board_rp2040.c). */
uint64_t sb_next_edge(const struct sb_core *c);
/* Emits the current tick's step edges up to `now` and returns the time of the next one (as
 * sb_next_edge): the cheap call for a board that wakes up for every edge. When `now` has reached
 * sb_next_deadline() it does what sb_poll(now) does (tick boundary, watchdog, inputs). */
uint64_t sb_advance(struct sb_core *c, uint64_t now);
/* Largest pulse count per tick the step width allows (with or without a direction change). */
uint32_t sb_max_pulses(const struct sb_config *cfg, int dir_change);
void sb_send_status(struct sb_core *c);
/* The home switch of `axis` went to `closed` at time t_ns (a board's input interrupt, with its
 * timestamp): latches that axis's counter as it was at t_ns -- the rising edges the core emitted
 * after t_ns in the current tick are not counted -- and reports it in every STATUS. Call it by the
 * end of the tick the transition happened in (an earlier tick's edges are not recomputed). Safe to
 * call from board_step() (it only writes the latch). */
void sb_home_edge(struct sb_core *c, uint8_t axis, uint8_t closed, uint64_t t_ns);
/* A fault the board detected (e.g. SB_F_LATE): stops stepping now, as an E-stop does. */
void sb_board_fault(struct sb_core *c, uint16_t bits);

/* Board-independent event hook for logging (the host build prints; a board may leave it empty). */
void board_event(const char *what, const struct sb_core *c);

#endif
