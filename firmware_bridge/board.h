/* board.h - everything the portable core needs from a board. One header, five functions.
 *
 * A board layer (board_host.c for a Linux process on a pty, board_rp2040.c as a documented
 * skeleton of a real port) implements these and calls the core (core.h): sb_rx() with the bytes
 * it receives, sb_poll() whenever the clock passes sb_next_deadline() or an input changes.
 * Times are nanoseconds of a monotonic clock that never wraps (64 bit).
 */
#ifndef SB_BOARD_H
#define SB_BOARD_H

#include <stddef.h>
#include <stdint.h>

/* Input bits of board_inputs() */
#define SB_IN_HOME(axis) (1u << (axis))        /* home switches, bits 0..4 (reported only) */
#define SB_IN_ESTOP (1u << 5)                  /* E-stop chain open: stop stepping at once */
#define SB_IN_ALARM(axis) (1u << (8 + (axis)))   /* drive alarm lines, bits 8..12: stop at once */
#define SB_IN_ALARM_ALL (0x1Fu << 8)

/* A step output edge (level 1 = rising: the drive counts a step) or a direction change, at time
 * t_ns. The core emits them in time order per axis, never earlier than the time it schedules and
 * never later than the poll that passes it: a board with hardware timing (timer compare, PIO)
 * queues them; the host build logs them with their computed timestamps. */
void board_step(uint8_t axis, uint8_t level, uint64_t t_ns, uint32_t tick);
void board_dir(uint8_t axis, uint8_t dir, uint64_t t_ns, uint32_t tick);

/* The start of tick `tick` at t_ns (for the host build's edge log; a board may ignore it). */
void board_tick_start(uint32_t tick, uint64_t t_ns);

/* Bytes to the host (the whole frame; the board may buffer). */
void board_tx(const uint8_t *buf, size_t n);

/* Current inputs (SB_IN_* bits, active = 1 after the board's own polarity handling). */
uint16_t board_inputs(void);

/* Strain ADC channels (raw counts, signed); zeros where the board does not sample them. */
void board_adc(int16_t out[3]);

/* Short board name reported by IDENT (e.g. "host-pty", "rp2040"). */
extern const char board_name[];

#endif
