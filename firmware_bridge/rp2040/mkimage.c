/* mkimage.c - build-time tool (runs on the build machine) for the RP2040 image.
 *
 *   mkimage boot2 BOOT2.bin OUT.bin         pad boot2 to 252 bytes and append its CRC-32 (256 bytes)
 *   mkimage uf2 IMAGE.bin OUT.uf2           the flash image as UF2 blocks for drag-and-drop flashing
 *
 * The boot ROM runs boot2 only if its last 4 bytes (little-endian) hold the CRC-32/MPEG-2 of the
 * first 252: poly 0x04C11DB7, init 0xFFFFFFFF, MSB first, no final xor (check value of "123456789":
 * 0x0376E6E7). UF2 (Microsoft's USB flashing format): 512-byte blocks, each carrying 256 bytes to a
 * flash address, magics 0x0A324655 0x9E5D5157 ... 0x0AB16F30, flag 0x2000 "family id present"
 * with the RP2040's family id 0xE48BFF56; the Pico's boot ROM writes them in BOOTSEL mode. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define FLASH_BASE 0x10000000u
#define UF2_FLAG_FAMILY 0x00002000u
#define RP2040_FAMILY 0xe48bff56u

static uint32_t crc32_mpeg2(const uint8_t *p, size_t n)
{
    uint32_t c = 0xffffffffu;
    for (size_t i = 0; i < n; i++) {
        c ^= (uint32_t)p[i] << 24;
        for (int b = 0; b < 8; b++)
            c = (c & 0x80000000u) ? (c << 1) ^ 0x04c11db7u : c << 1;
    }
    return c;
}

static uint8_t *slurp(const char *path, size_t *n)
{
    FILE *f = fopen(path, "rb");
    uint8_t *buf;
    long len;
    if (!f || fseek(f, 0, SEEK_END) || (len = ftell(f)) < 0 || fseek(f, 0, SEEK_SET)) {
        perror(path);
        exit(1);
    }
    buf = malloc((size_t)len + 1);
    if (!buf || fread(buf, 1, (size_t)len, f) != (size_t)len) {
        fprintf(stderr, "mkimage: cannot read %s\n", path);
        exit(1);
    }
    fclose(f);
    *n = (size_t)len;
    return buf;
}

static void spit(const char *path, const uint8_t *p, size_t n)
{
    FILE *f = fopen(path, "wb");
    if (!f || fwrite(p, 1, n, f) != n || fclose(f)) {
        perror(path);
        exit(1);
    }
}

static void put32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}

int main(int argc, char **argv)
{
    size_t n;
    uint8_t *in;
    if (argc == 2 && !strcmp(argv[1], "check")) {   /* self-test: the catalogue check value */
        uint32_t c = crc32_mpeg2((const uint8_t *)"123456789", 9);
        printf("%08x\n", c);
        return c == 0x0376e6e7u ? 0 : 1;
    }
    if (argc != 4) {
        fprintf(stderr, "usage: mkimage boot2 BOOT2.bin OUT.bin | mkimage uf2 IMAGE.bin OUT.uf2 | mkimage check\n");
        return 2;
    }
    in = slurp(argv[2], &n);
    if (!strcmp(argv[1], "boot2")) {
        uint8_t out[256];
        if (n > 252) {
            fprintf(stderr, "mkimage: boot2 is %zu bytes; at most 252 fit before its CRC\n", n);
            return 1;
        }
        memset(out, 0, sizeof out);
        memcpy(out, in, n);
        put32(out + 252, crc32_mpeg2(out, 252));
        spit(argv[3], out, sizeof out);
        return 0;
    }
    if (!strcmp(argv[1], "uf2")) {
        uint32_t blocks = (uint32_t)((n + 255) / 256), i;
        uint8_t *out = calloc(blocks, 512);
        if (!out || n == 0)
            return 1;
        for (i = 0; i < blocks; i++) {
            uint8_t *b = out + 512u * i;
            size_t off = 256u * i, len = n - off < 256 ? n - off : 256;
            put32(b + 0, 0x0a324655u);
            put32(b + 4, 0x9e5d5157u);
            put32(b + 8, UF2_FLAG_FAMILY);
            put32(b + 12, FLASH_BASE + (uint32_t)off);
            put32(b + 16, 256);
            put32(b + 20, i);
            put32(b + 24, blocks);
            put32(b + 28, RP2040_FAMILY);
            memcpy(b + 32, in + off, len);
            put32(b + 508, 0x0ab16f30u);
        }
        spit(argv[3], out, 512u * blocks);
        return 0;
    }
    fprintf(stderr, "mkimage: unknown command %s\n", argv[1]);
    return 2;
}
