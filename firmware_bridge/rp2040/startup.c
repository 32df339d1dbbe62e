/* startup.c - the RP2040 image's vector table and reset handler (ARMv6-M, Cortex-M0+).
 *
 * boot2 (or, in the emulator, the harness) points VTOR at the table below, at 0x10000100, loads the
 * stack pointer from its first word and jumps to reset_handler. That copies the code, constants and
 * initialised data to SRAM (see memmap.ld), zeroes .bss and calls main(). It runs from flash and
 * calls nothing in SRAM before the copy is done. */
#include <stdint.h>

extern uint32_t __data_load[], __data_start[], __data_end[], __bss_start[], __bss_end[], __stack_top[];
extern int main(void);

void reset_handler(void) __attribute__((section(".reset"), noreturn, used));
void isr_default(void) __attribute__((section(".reset")));

/* the handlers board_rp2040.c defines; any other exception or IRQ stops in isr_default */
void isr_systick(void) __attribute__((weak, alias("isr_default")));
void isr_timer0(void) __attribute__((weak, alias("isr_default")));
void isr_io_bank0(void) __attribute__((weak, alias("isr_default")));
void isr_uart0(void) __attribute__((weak, alias("isr_default")));
void isr_hardfault(void) __attribute__((weak, alias("isr_default")));

typedef void (*vector_t)(void);

__attribute__((section(".vectors"), used)) const vector_t vector_table[16 + 32] = {
    (vector_t)(uintptr_t)__stack_top,   /* initial main stack pointer */
    reset_handler,
    isr_default,          /* NMI */
    isr_hardfault,        /* HardFault */
    0, 0, 0, 0, 0, 0, 0,  /* reserved */
    isr_default,          /* SVCall */
    0, 0,                 /* reserved */
    isr_default,          /* PendSV */
    isr_systick,          /* SysTick */
    /* IRQ 0..31 (RP2040 datasheet 2.3.2) */
    isr_timer0, isr_default, isr_default, isr_default,        /* 0-3 TIMER_IRQ_0..3 */
    isr_default, isr_default, isr_default, isr_default,       /* 4 PWM, 5 USBCTRL, 6 XIP, 7 PIO0_0 */
    isr_default, isr_default, isr_default, isr_default,       /* 8 PIO0_1, 9 PIO1_0, 10 PIO1_1, 11 DMA_0 */
    isr_default, isr_io_bank0, isr_default, isr_default,      /* 12 DMA_1, 13 IO_BANK0, 14 IO_QSPI, 15 SIO_PROC0 */
    isr_default, isr_default, isr_default, isr_default,       /* 16 SIO_PROC1, 17 CLOCKS, 18 SPI0, 19 SPI1 */
    isr_uart0, isr_default, isr_default, isr_default,         /* 20 UART0, 21 UART1, 22 ADC_FIFO, 23 I2C0 */
    isr_default, isr_default, isr_default, isr_default,       /* 24 I2C1, 25 RTC, 26-31 unused */
    isr_default, isr_default, isr_default, isr_default,
};

void reset_handler(void)
{
    volatile uint32_t *src = __data_load, *dst = __data_start;   /* volatile: no memcpy call */
    while (dst < __data_end)
        *dst++ = *src++;
    for (dst = __bss_start; dst < __bss_end;)
        *dst++ = 0;
    main();
    for (;;)
        ;
}

/* An unexpected exception: stop here with interrupts off; the hardware watchdog then resets the
 * chip (it is not fed any more), and the host sees the link drop. */
void isr_default(void)
{
    __asm volatile("cpsid i");
    for (;;)
        ;
}
