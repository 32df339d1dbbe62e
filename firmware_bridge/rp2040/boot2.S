/* boot2.S - the second-stage boot loader of the RP2040 image (the first 256 bytes of flash).
 *
 * The boot ROM copies these 256 bytes to SRAM and runs them only if their last 4 bytes hold the
 * CRC-32 of the first 252 (poly 0x04C11DB7, init 0xFFFFFFFF, MSB first, no final xor: the
 * CRC-32/MPEG-2 variant); `mkimage boot2` computes it at build time. boot2's job is to set the
 * flash interface (the SSI in XIP mode, datasheet 2.8.1 and 4.10) so that code can execute in
 * place from 0x10000000, then enter the image's vector table at 0x10000100.
 *
 * This one uses the slow generic serial read command 03h (24-bit address, no dummy cycles), which
 * every QSPI flash chip answers, at clk_sys / 4. The bridge copies its code to SRAM at start, so
 * the flash speed matters only while it boots. Position-independent (the ROM runs it from SRAM).
 *
 * Verified here only by its CRC: the emulator (rp2040js) has no boot ROM and starts the image at
 * its vector table directly; a real Pico runs this code.
 */
    .syntax unified
    .cpu cortex-m0plus
    .thumb

    .equ XIP_SSI_BASE, 0x18000000
    .equ SSI_CTRLR0, 0x00
    .equ SSI_CTRLR1, 0x04
    .equ SSI_SSIENR, 0x08
    .equ SSI_BAUDR, 0x14
    .equ SSI_SPI_CTRLR0, 0xf4
    /* CTRLR0: standard SPI frame format (SPI_FRF 0), 32-bit data frames (DFS_32 = 31),
     * transfer mode EEPROM read (TMOD = 3: send command + address, then receive) */
    .equ CTRLR0_XIP, (31 << 16) | (3 << 8)
    /* SPI_CTRLR0: XIP command 03h, 8-bit instruction (INST_L = 2), 24-bit address (ADDR_L = 6,
     * in 4-bit units), instruction and address both in standard SPI (TRANS_TYPE 0) */
    .equ SPI_CTRLR0_XIP, (0x03 << 24) | (2 << 8) | (6 << 2) | 0
    .equ VTOR, 0xe000ed08
    .equ IMAGE_VECTORS, 0x10000100

    .section .boot2, "ax"
    .global _boot2
    .type _boot2, %function
    .thumb_func
_boot2:
    push {lr}                      /* 0 when entered from the boot ROM; a return address otherwise */
    ldr r3, =XIP_SSI_BASE
    movs r1, #0
    str r1, [r3, #SSI_SSIENR]      /* the SSI must be disabled to be reconfigured */
    movs r1, #4
    str r1, [r3, #SSI_BAUDR]       /* SCK = clk_sys / 4 */
    ldr r1, =CTRLR0_XIP
    str r1, [r3, #SSI_CTRLR0]
    movs r1, #0
    str r1, [r3, #SSI_CTRLR1]      /* NDF = 0: one 32-bit frame per XIP access */
    ldr r0, =(XIP_SSI_BASE + SSI_SPI_CTRLR0)
    ldr r1, =SPI_CTRLR0_XIP
    str r1, [r0]
    movs r1, #1
    str r1, [r3, #SSI_SSIENR]      /* enabled: reads of 0x10xxxxxx now fetch from flash */
    pop {r0}
    cmp r0, #0
    beq 1f
    bx r0                          /* called as a function: return */
1:  ldr r0, =IMAGE_VECTORS         /* from the boot ROM: enter the image through its vector table */
    ldr r1, =VTOR
    str r0, [r1]
    ldmia r0!, {r1, r2}            /* initial stack pointer, reset handler */
    msr msp, r1
    bx r2
    .ltorg
    .size _boot2, . - _boot2
