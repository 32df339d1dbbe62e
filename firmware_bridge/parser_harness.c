/* parser_harness.c - the bridge's frame parser on stdin, for the host-side fuzz test.
 * Prints one line per valid frame: "F <seq> <type> <payload hex>", then
 * "S <frames_ok> <bad_frames> <dropped_bytes>". Not part of the firmware. */
#include <stdio.h>

#include "proto.h"

int main(void)
{
    static struct sb_parser p;
    struct sb_frame f;
    int c, i;
    sb_parser_init(&p);
    while ((c = getchar()) != EOF) {
        if (!sb_parser_byte(&p, (uint8_t)c, &f))
            continue;
        do {
            printf("F %u %u ", f.seq, f.type);
            for (i = 0; i < f.len; i++)
                printf("%02x", f.payload[i]);
            printf("\n");
        } while (sb_parser_next(&p, &f));
    }
    printf("S %lu %lu %lu\n", (unsigned long)p.frames_ok, (unsigned long)p.bad_frames,
           (unsigned long)p.dropped_bytes);
    return 0;
}
