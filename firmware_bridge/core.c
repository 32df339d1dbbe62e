/* core.c - the portable bridge core (see core.h, PROTOCOL.md). */
#include "core.h"

#include <string.h>

#include "board.h"

#define NEVER UINT64_MAX
#define IDLE_STATUS_NS 10000000u   /* a STATUS every 10 ms while not stepping */

static void send(struct sb_core *c, uint8_t type, const uint8_t *p, size_t n)
{
    uint8_t buf[SB_FRAME_MAX];
    size_t len = sb_frame(buf, c->expect_seq, type, p, n);
    if (len)
        board_tx(buf, len);
}

static void send_ack(struct sb_core *c, uint8_t flags, uint8_t code, uint8_t type)
{
    uint8_t p[3];
    p[0] = flags;
    p[1] = code;
    p[2] = type;
    send(c, SB_T_ACK, p, 3);
}

uint32_t sb_max_pulses(const struct sb_config *cfg, int dir_change)
{
    uint32_t span = cfg->tick_ns - (dir_change ? cfg->dir_setup_ns : 0u);
    uint32_t n = span / (2u * cfg->step_width_ns);
    return n > 32767u ? 32767u : n;
}

static void status_why(struct sb_core *c, uint8_t why);

void sb_send_status(struct sb_core *c)
{
    status_why(c, SB_WHY_OTHER);
}

/* floor(ns / 1000) mod 2^32 without a 64-bit division (a Cortex-M0+ does those in software, slowly):
 * ns = h 2^32 + l and 2^32 = 4294967 x 1000 + 296, so ns / 1000 = h x 4294967 + (h x 296 + l) / 1000. */
static uint32_t us32(uint64_t ns)
{
    uint32_t q = 0;
    while (ns >> 32) {
        uint32_t h = (uint32_t)(ns >> 32);
        q += h * 4294967u;
        ns = (uint64_t)h * 296u + (uint32_t)ns;
    }
    return q + (uint32_t)ns / 1000u;
}

static void status_why(struct sb_core *c, uint8_t why)
{
    uint8_t p[SB_STATUS_LEN];
    int16_t adc[SB_NADC];
    uint32_t bad = c->parser.bad_frames;
    int i;
    memset(p, 0, sizeof p);
    board_adc(adc);
    p[0] = c->state;
    p[1] = c->q_n;
    sb_put_u16(p + 2, c->faults);
    sb_put_u16(p + 4, c->inputs);
    sb_put_u16(p + 6, (uint16_t)(bad > 0xFFFFu ? 0xFFFFu : bad));
    sb_put_u32(p + 8, c->started);
    sb_put_u32(p + 12, c->done);
    sb_put_u32(p + 16, c->next_tick);
    for (i = 0; i < SB_NAXES; i++) {
        sb_put_u32(p + 20 + 4 * i, (uint32_t)c->counters[i]);
        sb_put_u32(p + 40 + 4 * i, (uint32_t)c->not_executed[i]);
    }
    sb_put_u32(p + 60, c->dropped_ticks);
    for (i = 0; i < SB_NADC; i++)
        sb_put_u16(p + 64 + 2 * i, (uint16_t)adc[i]);
    sb_put_u16(p + 70, c->underruns);
    sb_put_u32(p + 72, us32(c->now));
    sb_put_u32(p + 76, us32(c->last_tick_rx));
    sb_put_u32(p + 80, us32(c->fault_time));
    p[84] = why;
    p[85] = (uint8_t)(c->cfg.queue - c->q_n);
    for (i = 0; i < SB_NAXES; i++) {
        sb_put_u32(p + 86 + 4 * i, (uint32_t)c->home_latch[i]);
        p[106 + i] = c->home_edges[i];
    }
    p[111] = c->home_level;
    send(c, SB_T_STATUS, p, sizeof p);
}

static void copy_str(uint8_t *dst, const char *s, size_t room)
{
    size_t n = strlen(s);
    memcpy(dst, s, n < room ? n : room);   /* NUL-padded by the caller's memset */
}

static void send_ident(struct sb_core *c)
{
    uint8_t p[50];
    memset(p, 0, sizeof p);
    memcpy(p, "PMSB", 4);
    sb_put_u16(p + 4, SB_PROTO_VERSION);
    p[6] = SB_NAXES;
    p[7] = SB_QUEUE_MAX;
    sb_put_u32(p + 8, c->cfg.tick_ns);
    sb_put_u32(p + 12, c->cfg.step_width_ns);
    sb_put_u32(p + 16, c->cfg.dir_setup_ns);
    sb_put_u32(p + 20, c->cfg.watchdog_us);
    p[24] = c->cfg.queue;
    p[25] = c->cfg.prime;
    copy_str(p + 26, SB_FW_VERSION, 8);
    copy_str(p + 34, board_name, 16);
    send(c, SB_T_IDENT_REPLY, p, sizeof p);
}

void sb_init(struct sb_core *c, uint64_t now_ns)
{
    memset(c, 0, sizeof *c);
    sb_parser_init(&c->parser);
    c->cfg.tick_ns = 1000000u;
    c->cfg.step_width_ns = 2500u;
    c->cfg.dir_setup_ns = 5000u;
    c->cfg.watchdog_us = 50000u;
    c->watchdog_ns = 50000000u;
    c->cfg.queue = SB_QUEUE_MAX;
    c->cfg.prime = 2;
    c->status_every = 1;
    c->state = SB_S_IDLE;
    c->now = now_ns;
    c->next_idle_status = now_ns;
    for (int i = 0; i < SB_NAXES; i++)
        c->ax[i].dir = 1;
}

/* ---------------------------------------------------------------- step generator */

static uint64_t axis_next(const struct sb_axis *a)
{
    uint64_t rise = a->k < a->n ? a->t_first + a->a : NEVER;
    return a->fall && a->fall <= rise ? a->fall : rise;
}

/* Every axis's next edge and the earliest of them, after the axes changed. */
static void refresh_next(struct sb_core *c)
{
    int i;
    c->next_edge = NEVER;
    for (i = 0; i < SB_NAXES; i++) {
        c->ax[i].next = axis_next(&c->ax[i]);
        if (c->ax[i].next < c->next_edge)
            c->next_edge = c->ax[i].next;
    }
}

/* Emits every edge of the current tick up to and including time `until`. Axes whose next edge is
 * later are not visited: a board that wakes up for each edge pays for the axes that step. */
static void advance(struct sb_core *c, uint64_t until)
{
    int i;
    if (!c->cur_active || c->next_edge > until)
        return;
    c->next_edge = NEVER;
    for (i = 0; i < SB_NAXES; i++) {
        struct sb_axis *a = &c->ax[i];
        if (a->next <= until) {
            for (;;) {
                uint64_t rise = a->k < a->n ? a->t_first + a->a : NEVER;
                if (a->fall && a->fall <= rise) {
                    if (a->fall > until)
                        break;
                    board_step((uint8_t)i, 0, a->fall, c->cur_index);
                    a->fall = 0;
                    continue;
                }
                if (rise > until)
                    break;
                c->counters[i] += a->sign;      /* counted first: a latch taken in board_step includes it */
                board_step((uint8_t)i, 1, rise, c->cur_index);
                a->k++;
                a->fall = rise + c->cfg.step_width_ns;
                /* Bresenham: a_k = floor((2k+1) s / 2n) without a division per step */
                a->a += a->q;
                a->e += 2u * a->r;
                if (a->e >= 2u * a->n) {
                    a->a++;
                    a->e -= 2u * a->n;
                }
            }
            a->next = axis_next(a);
        }
        if (a->next < c->next_edge)
            c->next_edge = a->next;
    }
}

static void fault(struct sb_core *c, uint16_t bits, uint64_t t);

/* Rising edges of the current tick of axis `a` at or before time t: edge i is at
 * t_first + floor((2i+1) s / 2n), so i counts while (2i+1) s < 2n (t - t_first + 1). */
static uint32_t edges_until(const struct sb_axis *a, uint64_t t)
{
    uint64_t x, m;
    if (a->n == 0 || t < a->t_first)
        return 0;
    x = 2u * (uint64_t)a->n * (t - a->t_first + 1u);
    m = ((x - 1u) / a->s + 1u) / 2u;
    return m > a->n ? a->n : (uint32_t)m;
}

void sb_home_edge(struct sb_core *c, uint8_t axis, uint8_t closed, uint64_t t_ns)
{
    const struct sb_axis *a;
    int32_t n;
    if (axis >= SB_NAXES)
        return;
    a = &c->ax[axis];
    n = c->counters[axis];
    if (c->cur_active) {
        uint32_t at = t_ns < c->cur_start ? 0u : edges_until(a, t_ns);
        if (at < a->k)
            n -= a->sign * (int32_t)(a->k - at);     /* emitted, but after the transition */
    }
    c->home_latch[axis] = n;
    c->home_edges[axis]++;
    if (closed)
        c->home_level = (uint8_t)(c->home_level | (1u << axis));
    else
        c->home_level = (uint8_t)(c->home_level & ~(1u << axis));
}

static void start_tick(struct sb_core *c, uint64_t t0)
{
    struct sb_tick *tk = &c->q[c->q_head];
    int i;
    c->q_head = (uint8_t)((c->q_head + 1) % SB_QUEUE_MAX);
    c->q_n--;
    c->cur_active = 1;
    c->cur_index = tk->index;
    c->cur_start = t0;
    board_tick_start(tk->index, t0);
    for (i = 0; i < SB_NAXES; i++) {
        struct sb_axis *a = &c->ax[i];
        int32_t p = tk->pulses[i];
        uint32_t n = (uint32_t)(p < 0 ? -p : p);
        int8_t sign = (int8_t)(p < 0 ? -1 : 1);
        int change = n > 0 && sign != a->dir;
        uint64_t d = change ? c->cfg.dir_setup_ns : 0u;
        a->n = n;
        a->k = 0;
        a->sign = sign;
        a->fall = 0;
        if (n == 0)
            continue;
        if (n > sb_max_pulses(&c->cfg, change)) {
            /* cannot be emitted with the configured step width: refuse the whole tick */
            int j;
            for (j = 0; j < SB_NAXES; j++) {
                int32_t pj = tk->pulses[j];
                c->ax[j].n = (uint32_t)(pj < 0 ? -pj : pj);
                c->ax[j].sign = (int8_t)(pj < 0 ? -1 : 1);
                c->ax[j].k = 0;
                c->ax[j].fall = 0;
            }
            c->started++;
            fault(c, SB_F_OVERSPEED, t0);
            return;
        }
        if (change) {
            board_dir((uint8_t)i, sign > 0, t0, tk->index);
            a->dir = sign;
        }
        a->t_first = t0 + d;
        {
            /* the span fits 32 bits (tick_ns <= 1e8, checked by CONFIG): 32-bit divisions, which a
             * Cortex-M0+ does in hardware (RP2040 SIO) or much faster than 64-bit ones */
            uint32_t s = c->cfg.tick_ns - (uint32_t)d;
            a->s = s;
            a->q = s / n;
            a->r = s % n;
            a->a = s / (2u * n);
            a->e = s % (2u * n);
        }
    }
    refresh_next(c);
    c->started++;
    if (c->status_every && c->started % c->status_every == 0)
        status_why(c, SB_WHY_TICK);   /* counters = everything before this tick, exactly */
}

/* Stops stepping at time t (edges up to t already emitted), latches `bits`, accounts for what
 * was not executed and reports it. */
static void fault(struct sb_core *c, uint16_t bits, uint64_t t)
{
    int i, j;
    if (c->state == SB_S_FAULT) {
        c->faults |= bits;
        return;
    }
    if (c->cur_active) {
        int partial = 0;
        for (i = 0; i < SB_NAXES; i++) {
            struct sb_axis *a = &c->ax[i];
            uint32_t rem = a->n - a->k;
            if (rem) {
                partial = 1;
                c->not_executed[i] += a->sign * (int32_t)rem;
                a->n = a->k;
            }
            if (a->fall) {             /* a started pulse keeps its full width */
                board_step((uint8_t)i, 0, a->fall, c->cur_index);
                a->fall = 0;
            }
        }
        if (partial)
            c->dropped_ticks++;
        c->cur_active = 0;
    }
    for (j = 0; j < c->q_n; j++) {
        struct sb_tick *tk = &c->q[(c->q_head + j) % SB_QUEUE_MAX];
        for (i = 0; i < SB_NAXES; i++)
            c->not_executed[i] += tk->pulses[i];
        c->dropped_ticks++;
    }
    c->q_n = 0;
    c->faults |= bits;
    c->fault_time = t;
    c->state = SB_S_FAULT;
    board_event("fault", c);
    sb_send_status(c);
}

void sb_board_fault(struct sb_core *c, uint16_t bits)
{
    fault(c, bits, c->now);
}

static void finish_tick(struct sb_core *c, uint64_t t)
{
    advance(c, t);
    c->cur_active = 0;
    c->done++;
    if (c->q_n && (c->state == SB_S_RUNNING || c->state == SB_S_DRAINING)) {
        start_tick(c, t);
        return;
    }
    if (c->state == SB_S_DRAINING) {
        c->state = SB_S_IDLE;
        board_event("idle", c);
        sb_send_status(c);
    } else if (c->state == SB_S_RUNNING) {
        c->underruns++;
        c->state = SB_S_ARMED;      /* wait for `prime` ticks again */
    }
}

/* ---------------------------------------------------------------- commands */

static uint8_t do_config(struct sb_core *c, const struct sb_frame *f)
{
    struct sb_config n;
    if (f->len != 18)
        return SB_E_ARGS;
    if (c->state == SB_S_RUNNING || c->state == SB_S_DRAINING || c->q_n)
        return SB_E_BUSY;
    n.tick_ns = sb_get_u32(f->payload);
    n.step_width_ns = sb_get_u32(f->payload + 4);
    n.dir_setup_ns = sb_get_u32(f->payload + 8);
    n.watchdog_us = sb_get_u32(f->payload + 12);
    n.queue = f->payload[16];
    n.prime = f->payload[17];
    if (n.tick_ns < 50000u || n.tick_ns > 100000000u || n.step_width_ns < 100u ||
        2u * n.step_width_ns > n.tick_ns || n.dir_setup_ns + 2u * n.step_width_ns > n.tick_ns ||
        n.watchdog_us < 1000u || n.watchdog_us > 10000000u ||
        n.queue < 2 || n.queue > SB_QUEUE_MAX || n.prime < 1 || n.prime > n.queue)
        return SB_E_ARGS;
    c->cfg = n;
    c->watchdog_ns = (uint64_t)n.watchdog_us * 1000u;
    return SB_E_OK;
}

static void check_inputs(struct sb_core *c, uint64_t t)
{
    uint16_t bits = 0;
    if (c->inputs & SB_IN_ESTOP)
        bits |= SB_F_ESTOP;
    if (c->inputs & SB_IN_ALARM_ALL)
        bits |= SB_F_ALARM;
    if (bits && (c->faults & bits) != bits)
        fault(c, bits, t);
}

static uint8_t do_reset(struct sb_core *c, const struct sb_frame *f)
{
    int i;
    if (f->len != 20)
        return SB_E_ARGS;
    if (c->state == SB_S_RUNNING || c->state == SB_S_DRAINING || c->q_n)
        return SB_E_BUSY;
    c->faults = 0;
    c->q_n = 0;
    c->cur_active = 0;
    for (i = 0; i < SB_NAXES; i++) {
        int32_t n = (int32_t)sb_get_u32(f->payload + 4 * i);
        c->home_latch[i] = (int32_t)((uint32_t)c->home_latch[i] + (uint32_t)n - (uint32_t)c->counters[i]);
        /* the latches move with the counters */
        c->counters[i] = n;
        c->not_executed[i] = 0;
    }
    for (i = 0; i < SB_NAXES; i++) {     /* direction outputs to + : the host knows where they are */
        if (c->ax[i].dir != 1)
            board_dir((uint8_t)i, 1, c->now, 0);
        c->ax[i].dir = 1;
    }
    c->dropped_ticks = 0;
    c->started = c->done = c->next_tick = 0;
    c->underruns = 0;
    c->fault_time = 0;
    c->last_tick_rx = c->now;
    c->state = SB_S_ARMED;
    check_inputs(c, c->now);        /* E-stop still open or a drive in alarm: latched again */
    board_event("reset", c);
    return c->state == SB_S_FAULT ? SB_E_FAULT : SB_E_OK;
}

static uint8_t do_tick(struct sb_core *c, const struct sb_frame *f, uint8_t *flags)
{
    struct sb_tick *tk;
    uint32_t index;
    int i;
    if (f->len != 14)
        return SB_E_ARGS;
    index = sb_get_u32(f->payload);
    if (c->state == SB_S_IDLE || c->state == SB_S_DRAINING)
        return SB_E_STATE;
    if (c->state != SB_S_FAULT && index != c->next_tick)
        fault(c, SB_F_PROTOCOL, c->now);
    for (i = 0; i < SB_NAXES && c->state != SB_S_FAULT; i++) {
        int16_t p = (int16_t)sb_get_u16(f->payload + 4 + 2 * i);
        if ((uint32_t)(p < 0 ? -p : p) > sb_max_pulses(&c->cfg, 0))
            fault(c, SB_F_OVERSPEED, c->now);
    }
    if (c->state == SB_S_FAULT) {
        /* refused: never executed, reported as not executed */
        for (i = 0; i < SB_NAXES; i++)
            c->not_executed[i] += (int16_t)sb_get_u16(f->payload + 4 + 2 * i);
        c->dropped_ticks++;
        return (c->faults & SB_F_PROTOCOL) && index != c->next_tick ? SB_E_TICK
             : (c->faults & SB_F_OVERSPEED) ? SB_E_SPEED : SB_E_FAULT;
    }
    if (c->q_n >= c->cfg.queue) {
        *flags |= SB_ACK_FULL;
        return SB_E_OK;
    }
    tk = &c->q[(c->q_head + c->q_n) % SB_QUEUE_MAX];
    tk->index = index;
    for (i = 0; i < SB_NAXES; i++)
        tk->pulses[i] = (int16_t)sb_get_u16(f->payload + 4 + 2 * i);
    c->q_n++;
    c->next_tick++;
    c->last_tick_rx = c->now;
    if (c->state == SB_S_ARMED && !c->cur_active && c->q_n >= c->cfg.prime) {
        c->state = SB_S_RUNNING;
        start_tick(c, c->now);
    }
    return SB_E_OK;
}

static void handle(struct sb_core *c, const struct sb_frame *f)
{
    uint8_t d, flags = 0, code = SB_E_OK;
    if (f->type == SB_T_IDENT) {
        c->expect_seq = (uint8_t)(f->seq + 1);
        send_ident(c);
        return;
    }
    if (f->type == SB_T_STATUS_REQ) {
        sb_send_status(c);
        return;
    }
    d = (uint8_t)(f->seq - c->expect_seq);
    if (d != 0) {
        if (d < 128) {                       /* ahead: frames were lost; resend from expect_seq */
            if (f->type == SB_T_STOP)
                fault(c, SB_F_HOST_STOP, c->now);   /* stopping is always safe */
            send_ack(c, SB_ACK_NAK, SB_E_OK, f->type);
        } else {                             /* behind: a duplicate, already executed */
            send_ack(c, SB_ACK_DUP, SB_E_OK, f->type);
        }
        return;
    }
    switch (f->type) {
    case SB_T_CONFIG:
        code = do_config(c, f);
        break;
    case SB_T_RESET:
        code = do_reset(c, f);
        break;
    case SB_T_TICK:
        code = do_tick(c, f, &flags);
        break;
    case SB_T_END:
        if (c->state == SB_S_RUNNING || (c->state == SB_S_ARMED && (c->q_n || c->cur_active))) {
            c->state = SB_S_DRAINING;
            if (!c->cur_active)
                start_tick(c, c->now);
        } else if (c->state == SB_S_ARMED) {
            c->state = SB_S_IDLE;
            board_event("idle", c);
        }
        break;
    case SB_T_STOP:
        fault(c, SB_F_HOST_STOP, c->now);
        break;
    default:
        c->parser.bad_frames++;   /* unknown type: counted, refused, never executed */
        code = SB_E_ARGS;
        break;
    }
    if (flags & SB_ACK_FULL) {
        send_ack(c, flags, code, f->type);  /* not accepted: SEQ does not advance */
        return;
    }
    c->expect_seq++;
    if (code != SB_E_OK)
        flags |= SB_ACK_REJECT;
    c->last_code = code;
    send_ack(c, flags, code, f->type);
}

void sb_rx(struct sb_core *c, const uint8_t *buf, uint32_t n, uint64_t now_ns)
{
    struct sb_frame f;
    uint32_t i;
    sb_poll(c, now_ns);                 /* time first: a frame arriving after a deadline is late */
    for (i = 0; i < n; i++) {
        if (!sb_parser_byte(&c->parser, buf[i], &f))
            continue;
        do {
            handle(c, &f);
        } while (sb_parser_next(&c->parser, &f));
    }
}

/* ---------------------------------------------------------------- time */

/* The watchdog runs from the first tick after RESET until END or a fault: the host may take its
 * time between RESET and its first tick (planning), never between ticks. */
static int wd_armed(const struct sb_core *c)
{
    return (c->state == SB_S_ARMED || c->state == SB_S_RUNNING) && c->next_tick > 0;
}

uint64_t sb_next_deadline(const struct sb_core *c)
{
    uint64_t t = NEVER;
    if (c->cur_active)
        t = c->cur_start + c->cfg.tick_ns;
    if (wd_armed(c)) {
        uint64_t w = c->last_tick_rx + c->watchdog_ns;
        if (w < t)
            t = w;
    }
    if (c->state != SB_S_RUNNING && c->state != SB_S_DRAINING && c->next_idle_status < t)
        t = c->next_idle_status;
    return t;
}

uint64_t sb_next_edge(const struct sb_core *c)
{
    return c->cur_active ? c->next_edge : NEVER;
}

uint64_t sb_advance(struct sb_core *c, uint64_t now)
{
    if (now >= sb_next_deadline(c)) {
        sb_poll(c, now);
    } else if (now > c->now) {
        advance(c, now);
        c->now = now;
    }
    return sb_next_edge(c);
}

void sb_poll(struct sb_core *c, uint64_t now)
{
    if (now < c->now)
        now = c->now;
    for (;;) {
        uint64_t bound = c->cur_active ? c->cur_start + c->cfg.tick_ns : NEVER;
        uint64_t wd = wd_armed(c)
                          ? c->last_tick_rx + c->watchdog_ns : NEVER;
        if (bound <= now && bound <= wd) {
            c->now = bound;
            finish_tick(c, bound);
            continue;
        }
        if (wd <= now) {
            advance(c, wd);
            c->now = wd;
            fault(c, SB_F_WATCHDOG, wd);
            continue;
        }
        break;
    }
    advance(c, now);
    c->now = now;
    c->inputs = board_inputs();
    check_inputs(c, now);
    if (c->state != SB_S_RUNNING && c->state != SB_S_DRAINING && now >= c->next_idle_status) {
        sb_send_status(c);
        c->next_idle_status = now + IDLE_STATUS_NS;
    }
}
