/* proto.h - the bridge's wire format: framing, CRC-16 and the byte-stream parser.
 *
 * Frame (all multi-byte payload fields little-endian; see PROTOCOL.md):
 *
 *   SYNC(0x7E) LEN SEQ TYPE PAYLOAD[LEN-6] CRC_HI CRC_LO
 *
 * LEN is the whole frame length in bytes (6 .. SB_FRAME_MAX). The CRC is CRC-16/CCITT-FALSE
 * (poly 0x1021, init 0xFFFF, no reflection, no final xor) over LEN, SEQ, TYPE and the payload.
 * The parser resynchronises after garbage by dropping one byte and scanning for the next SYNC.
 * Portable C99, no allocation, no board dependency.
 */
#ifndef SB_PROTO_H
#define SB_PROTO_H

#include <stddef.h>
#include <stdint.h>

#define SB_SYNC 0x7E
#define SB_FRAME_MIN 6
#define SB_FRAME_MAX 125   /* < SYNC: a SYNC byte is never a valid LEN, so "~~" resynchronises at once */
#define SB_PAYLOAD_MAX (SB_FRAME_MAX - SB_FRAME_MIN)

#define SB_PROTO_VERSION 2   /* 2: STATUS carries the home-switch latches (112 bytes) */
#define SB_NAXES 5
#define SB_NADC 3
#define SB_STATUS_LEN 112

/* host -> bridge */
#define SB_T_IDENT 0x01      /* no payload; any SEQ; resets the expected SEQ to SEQ+1 */
#define SB_T_CONFIG 0x02     /* u32 tick_ns, u32 step_width_ns, u32 dir_setup_ns, u32 watchdog_us, u8 queue, u8 prime */
#define SB_T_RESET 0x03      /* i32 counters[5]: clear the fault latch, flush, set counters, arm */
#define SB_T_TICK 0x04       /* u32 tick, i16 pulses[5] */
#define SB_T_END 0x05        /* no payload: run out the queue, then idle (watchdog off) */
#define SB_T_STOP 0x06       /* no payload: stop stepping now, discard the queue, latch HOST_STOP */
#define SB_T_STATUS_REQ 0x07 /* no payload; not sequenced: answered with a STATUS */
/* bridge -> host (their SEQ field carries the next host SEQ the bridge expects: an ack) */
#define SB_T_ACK 0x81        /* u8 flags, u8 code, u8 type of the frame answered */
#define SB_T_STATUS 0x82     /* see sb_status_encode in core.c and PROTOCOL.md */
#define SB_T_IDENT_REPLY 0x83

/* ACK flags */
#define SB_ACK_NAK 0x01      /* out of sequence: resend from SEQ */
#define SB_ACK_FULL 0x02     /* tick queue full: not accepted, resend later */
#define SB_ACK_REJECT 0x04   /* accepted in sequence but refused (code says why); nothing executed */
#define SB_ACK_DUP 0x08      /* a duplicate of an executed frame: acknowledged again, not executed */

/* reject codes */
#define SB_E_OK 0
#define SB_E_BUSY 1          /* CONFIG while moving */
#define SB_E_ARGS 2          /* bad CONFIG values / payload length */
#define SB_E_FAULT 3         /* a fault is latched: RESET first */
#define SB_E_STATE 4         /* TICK while idle (no RESET) or after END */
#define SB_E_TICK 5          /* tick index out of order */
#define SB_E_SPEED 6         /* more pulses than fit in a tick with the step width */

uint16_t sb_crc16(const uint8_t *p, size_t n, uint16_t crc);

/* Builds a frame into out (>= SB_FRAME_MAX bytes); returns its length, 0 if the payload is too long. */
size_t sb_frame(uint8_t *out, uint8_t seq, uint8_t type, const uint8_t *payload, size_t n);

struct sb_frame {
    uint8_t seq, type, len;           /* len = payload length */
    uint8_t payload[SB_PAYLOAD_MAX];
};

struct sb_parser {
    uint8_t buf[2 * SB_FRAME_MAX];
    size_t n;
    uint32_t frames_ok;
    uint32_t dropped_bytes;            /* bytes skipped while resynchronising */
    uint32_t bad_frames;               /* candidate frames dropped: bad CRC or bad length */
};

void sb_parser_init(struct sb_parser *p);
/* Feeds one byte; returns 1 and fills *f when a valid frame completes, else 0. */
int sb_parser_byte(struct sb_parser *p, uint8_t b, struct sb_frame *f);
/* After a frame was returned, more complete frames may already sit in the buffer. */
int sb_parser_next(struct sb_parser *p, struct sb_frame *f);

/* little-endian helpers */
static inline void sb_put_u16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static inline void sb_put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}
static inline uint16_t sb_get_u16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
static inline uint32_t sb_get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

#endif
