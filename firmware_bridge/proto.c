/* proto.c - CRC-16/CCITT-FALSE, frame builder and the resynchronising parser (see proto.h). */
#include "proto.h"

#include <string.h>

/* CRC-16/CCITT-FALSE, a byte at a time from a 256-entry table (computed at compile time below): a
 * STATUS frame's CRC is about a tenth of the bit-at-a-time loop's cycles on a Cortex-M0+. */
#define T1(c) ((uint16_t)(((c) & 0x8000u) ? (((c) << 1) ^ 0x1021u) : ((c) << 1)))
#define T8(c) T1(T1(T1(T1(T1(T1(T1(T1((uint32_t)(c) << 8))))))))
#define R4(i) T8(i), T8((i) + 1), T8((i) + 2), T8((i) + 3)
#define R16(i) R4(i), R4((i) + 4), R4((i) + 8), R4((i) + 12)
#define R64(i) R16(i), R16((i) + 16), R16((i) + 32), R16((i) + 48)
static const uint16_t crc_table[256] = {R64(0), R64(64), R64(128), R64(192)};

uint16_t sb_crc16(const uint8_t *p, size_t n, uint16_t crc)
{
    size_t i;
    for (i = 0; i < n; i++)
        crc = (uint16_t)((crc << 8) ^ crc_table[((crc >> 8) ^ p[i]) & 0xffu]);
    return crc;
}

size_t sb_frame(uint8_t *out, uint8_t seq, uint8_t type, const uint8_t *payload, size_t n)
{
    uint16_t crc;
    if (n > SB_PAYLOAD_MAX)
        return 0;
    out[0] = SB_SYNC;
    out[1] = (uint8_t)(n + SB_FRAME_MIN);
    out[2] = seq;
    out[3] = type;
    if (n)
        memcpy(out + 4, payload, n);
    crc = sb_crc16(out + 1, n + 3, 0xFFFFu);
    out[4 + n] = (uint8_t)(crc >> 8);
    out[5 + n] = (uint8_t)crc;
    return n + SB_FRAME_MIN;
}

void sb_parser_init(struct sb_parser *p)
{
    memset(p, 0, sizeof *p);
}

static void drop(struct sb_parser *p, size_t k)
{
    memmove(p->buf, p->buf + k, p->n - k);
    p->n -= k;
}

/* Tries to take one frame off the front of the buffer. */
int sb_parser_next(struct sb_parser *p, struct sb_frame *f)
{
    for (;;) {
        size_t i = 0, len;
        uint16_t crc;
        while (i < p->n && p->buf[i] != SB_SYNC)
            i++;
        if (i) {
            p->dropped_bytes += (uint32_t)i;
            drop(p, i);
        }
        if (p->n < 2)
            return 0;
        len = p->buf[1];
        if (len < SB_FRAME_MIN || len > SB_FRAME_MAX) {
            p->bad_frames++;
            p->dropped_bytes++;
            drop(p, 1);               /* not a frame start: rescan from the next byte */
            continue;
        }
        if (p->n < len)
            return 0;                 /* wait for the rest */
        crc = sb_crc16(p->buf + 1, len - 3, 0xFFFFu);
        if (p->buf[len - 2] != (uint8_t)(crc >> 8) || p->buf[len - 1] != (uint8_t)crc) {
            p->bad_frames++;
            p->dropped_bytes++;
            drop(p, 1);               /* a good frame may start inside the bad one */
            continue;
        }
        f->seq = p->buf[2];
        f->type = p->buf[3];
        f->len = (uint8_t)(len - SB_FRAME_MIN);
        memcpy(f->payload, p->buf + 4, f->len);
        drop(p, len);
        p->frames_ok++;
        return 1;
    }
}

int sb_parser_byte(struct sb_parser *p, uint8_t b, struct sb_frame *f)
{
    if (p->n == sizeof p->buf) {      /* cannot happen (a frame is at most SB_FRAME_MAX): be safe */
        p->dropped_bytes++;
        drop(p, 1);
    }
    p->buf[p->n++] = b;
    return sb_parser_next(p, f);
}
