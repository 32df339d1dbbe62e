/* board_rp2040.c - SKELETON of a real board layer (Raspberry Pi RP2040). NOT BUILT, NOT TESTED.
 *
 * It shows what a port has to provide to run the same core (core.c, proto.c) on a microcontroller:
 * the five board.h functions, a clock, the byte link and the calls into the core. It is written
 * against the Raspberry Pi Pico SDK's names (pico/stdlib.h, hardware/pio.h, hardware/timer.h,
 * tusb.h) but has never been compiled; the TODO lines mark what a port must decide and measure.
 * The Makefile does not build it.
 *
 * Pin map (example; any GPIO works with PIO):
 *   STEP0..4 = GP2..GP6, DIR0..4 = GP7..GP11, ESTOP = GP12 (active low, pull-up, chain opens),
 *   ALARM0..4 = GP13..GP17 (active low), HOME0..4 = GP18..GP22, strain ADC = ADC0..2 (GP26..28).
 *
 * Timing model. The core computes every edge time (ns, 64-bit) ahead of real time and calls
 * board_step()/board_dir() in time order per axis. Here each axis has a PIO state machine that
 * takes (delay, level) words from its TX FIFO and drives the pin after `delay` PIO clocks: the
 * edge lands on the PIO clock (8 ns at 125 MHz) whatever the CPU is doing. The core must therefore
 * run ahead by the FIFO depth: board_poll_ahead() calls sb_poll(now + LOOKAHEAD) so a tick's edges
 * are queued before they are due. (The core's counters then count a step when it is queued, up
 * to LOOKAHEAD early: a port that reports counters at exact times must count in the PIO IRQ.)
 * 200 pulses/ms on 5 axes = 2 M edges/s: a pure timer-interrupt design (grbl style, one IRQ per
 * edge) does not reach that on a Cortex-M0+; PIO (or an STM32 timer in DMA/PWM burst mode) does.
 *
 * Link. USB CDC (TinyUSB): full speed (12 Mbit/s) carries the ~110 kB/s of TICK + ACK + STATUS
 * frames at 1 kHz easily; a 1 Mbaud UART (100 kB/s) does not, at one STATUS per tick
 * (PROTOCOL.md, "Bandwidth"): set status_every = 2 or more there.
 *
 * Inputs. E-stop and alarm lines raise a GPIO IRQ that calls sb_poll(now) at once (the core
 * stops stepping at that time and drops what is queued); the PIO FIFOs must be drained (pio_sm_clear_fifos)
 * and the STEP pins forced low after a pulse's width in board_stop() - TODO: add a board_stop()
 * hook to board.h when the first port needs it (the host build has no FIFOs to drain).
 * Home switches raise a GPIO IRQ too, timestamped at entry: sb_home_edge(&core, axis, level, t)
 * latches the counter as it was at t, not counting the steps the core queued ahead of t in the
 * current tick. LOOKAHEAD must stay inside one tick for that to be exact (an earlier tick's steps
 * are not recomputed); the error is then the IRQ entry latency x the step rate.
 */
#if 0   /* skeleton: not compiled */

#include "pico/stdlib.h"
#include "hardware/adc.h"
#include "hardware/pio.h"
#include "hardware/timer.h"
#include "tusb.h"

#include "board.h"
#include "core.h"

const char board_name[] = "rp2040";

#define LOOKAHEAD_NS 200000u           /* TODO: measure the FIFO depth needed at 2 M edges/s */
static const uint STEP_PIN[5] = {2, 3, 4, 5, 6};
static const uint DIR_PIN[5] = {7, 8, 9, 10, 11};
static struct sb_core core;
static uint64_t last_edge_ns[5];       /* per axis: time of the last queued edge */

static uint64_t now_ns(void) { return time_us_64() * 1000u; }   /* TODO: a finer clock (PIO counter) */

void board_step(uint8_t axis, uint8_t level, uint64_t t_ns, uint32_t tick)
{
    (void)tick;
    /* PIO program "edge": pull delay, pull level; wait delay clocks; set pin. 8 ns per clock. */
    uint32_t delay = (uint32_t)((t_ns - last_edge_ns[axis]) / 8u);
    last_edge_ns[axis] = t_ns;
    pio_sm_put_blocking(pio0, axis, (delay << 1) | level);   /* TODO: pio1 for axis 4 (4 SMs per PIO) */
}

void board_dir(uint8_t axis, uint8_t dir, uint64_t t_ns, uint32_t tick)
{
    (void)t_ns;
    (void)tick;
    /* The core sets DIR at the tick start, after the previous pulse's falling edge and at least
     * dir_setup_ns before the next rising edge; with edges queued ahead, DIR must go through the
     * same PIO FIFO (a side-set pin) so it changes at its time, not when queued. TODO. */
    gpio_put(DIR_PIN[axis], dir);
}

void board_tick_start(uint32_t tick, uint64_t t_ns) { (void)tick; (void)t_ns; }

void board_tx(const uint8_t *buf, size_t n)
{
    tud_cdc_write(buf, (uint32_t)n);
    tud_cdc_write_flush();
}

uint16_t board_inputs(void)
{
    uint16_t v = 0;
    for (int a = 0; a < 5; a++) {
        if (!gpio_get(18 + a)) v |= SB_IN_HOME(a);
        if (!gpio_get(13 + a)) v |= SB_IN_ALARM(a);
    }
    if (gpio_get(12)) v |= SB_IN_ESTOP;    /* chain open = pin pulled high */
    return v;
}

void board_adc(int16_t out[3])
{
    for (int i = 0; i < 3; i++) {
        adc_select_input(i);
        out[i] = (int16_t)adc_read();      /* TODO: bridge amplifier offset, filtering, sample clock */
    }
}

void board_event(const char *what, const struct sb_core *c) { (void)what; (void)c; }

static void on_input_irq(uint gpio, uint32_t events)
{
    (void)gpio;
    (void)events;
    sb_poll(&core, now_ns());              /* E-stop / alarm: stop at this time */
    /* TODO: a home pin: sb_home_edge(&core, axis_of(gpio), gpio_get(gpio), t_entry) */
}

int main(void)
{
    stdio_init_all();
    adc_init();
    /* TODO: load the PIO "edge" program into 5 state machines, init STEP/DIR/input pins, IRQs */
    for (uint g = 12; g <= 17; g++)
        gpio_set_irq_enabled_with_callback(g, GPIO_IRQ_EDGE_FALL | GPIO_IRQ_EDGE_RISE, true, on_input_irq);
    sb_init(&core, now_ns());
    for (;;) {
        uint8_t buf[64];
        tud_task();
        if (tud_cdc_available()) {
            uint32_t n = tud_cdc_read(buf, sizeof buf);
            sb_rx(&core, buf, n, now_ns());
        }
        sb_poll(&core, now_ns() + LOOKAHEAD_NS);   /* queue edges ahead into the PIO FIFOs */
    }
}

#endif
