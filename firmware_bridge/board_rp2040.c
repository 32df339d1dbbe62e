/* board_rp2040.c - the RP2040 board layer: the portable core (core.c, proto.c) on a Raspberry Pi
 * RP2040 (a Pico), bare metal, without the Pico SDK. Built by `make -C firmware_bridge rp2040`
 * into build/rp2040/bridge.elf, .bin and .uf2 (startup, boot2 and linker script in rp2040/).
 *
 * Pin map (Raspberry Pi Pico header; levels are 3.3 V, see docs/stepdir.md for the wiring):
 *   GP0  UART0 TX  -> host            GP1  UART0 RX  <- host           (3 Mbaud, 8N1)
 *   GP2..GP6   STEP L1 L2 L3 X Y      (high = step; a step counts at its rising edge)
 *   GP7..GP11  DIR  L1 L2 L3 X Y      (high = positive)
 *   GP12       ENABLE                 (high = drives enabled: armed, not faulted)
 *   GP13       E-STOP in              (high = chain open = stop; pull-up, NC chain to GND)
 *   GP14       ALARM in               (low = a drive in alarm; pull-up, the drives' open-collector
 *                                      alarm outputs in parallel; reported on every axis)
 *   GP15..GP19 HOME L1 L2 L3 X Y in   (low = switch closed; pull-up, NO switches to GND)
 *   GP25       TICK strobe            (toggles at every tick start; the Pico's LED)
 *   GP26..GP28 ADC0..2 strain, chains 1..3 (0..3.3 V from an external bridge amplifier, 12 bit)
 *
 * Host link: UART0. The emulator this image is tested in emulates the UART; a USB CDC port would
 * need a USB device stack (the Pico SDK's TinyUSB is not packaged for Debian, and the emulator
 * does not run one). At 3 Mbaud (300 kB/s) the link carries the ~130 kB/s of TICK + ACK + STATUS
 * frames at 1 kHz; use a USB-serial adapter that does 3 Mbaud (FT232H, CP2102N) and set
 * [hal.stepdir] baud = 3000000.
 *
 * Timing. Clock: XOSC 12 MHz -> PLL_SYS 125 MHz (clk_sys = clk_peri), PLL_USB 48 MHz (clk_adc).
 * Time base: the SysTick counter at clk_sys, extended to 64 bits in software: 8 ns per cycle.
 * Step generation uses timer wake-ups and SIO GPIO writes, as Klipper's RP2040 port does, not PIO:
 * the main loop asks the core for its next edge (sb_next_edge) and deadline, sleeps on TIMER alarm 0
 * (1 us) until shortly before, spins on the cycle clock to the edge time and calls sb_poll, whose
 * board_step() writes the pin. An edge is never written before its time. When the loop is late (a
 * frame being handled, a STATUS being framed) board_step() still keeps the configured high time,
 * low time and direction set-up on the pins by waiting, so a late edge is later, never shorter.
 *
 * UART RX: an interrupt moves bytes into a ring; the main loop feeds them to the core a few at a
 * time between edges. TX: the core's frames go into a ring the main loop drains into the FIFO.
 * Inputs: E-stop, alarm and home pins raise a GPIO interrupt that wakes the loop; the core reads
 * them at every poll (board_inputs). The hardware watchdog resets the chip if the main loop stops
 * for WDOG_US; a chip reset drops the link, and the drives' ENABLE goes low with the reset.
 */
#include <stdint.h>
#include <string.h>

#include "board.h"
#include "core.h"
#include "rp2040/rp2040.h"

const char board_name[] = "rp2040";

#define PIN_UART_TX 0u
#define PIN_UART_RX 1u
#define PIN_STEP0 2u
#define PIN_DIR0 7u
#define PIN_ENABLE 12u
#define PIN_ESTOP 13u
#define PIN_ALARM 14u
#define PIN_HOME0 15u
#define PIN_TICK 25u
#define ADC_CH0 0u                 /* GP26 */

#define CLK_SYS_HZ 125000000u
#define NS_PER_CYCLE 8u            /* 125 MHz */
#define UART_BAUD 3000000u
#define WDOG_US 100000u            /* hardware watchdog: the main loop feeds it every iteration */
#define SPIN_NS 4000u              /* closer than this to an event: spin instead of sleeping */
#define LATE_NS 200000u            /* an edge due longer ago than this: fallen behind, stop (SB_F_LATE) */
#define RX_CHUNK 32u               /* bytes fed to the core at once (edges come in between) */
#define RX_BATCH 16u               /* bytes worth waking the core for ... */
#define RX_WAIT_US 15u             /* ... or the age of the oldest (a frame's tail) */

#define STEP_MASK (0x1fu << PIN_STEP0)
#define DIR_MASK (0x1fu << PIN_DIR0)
#define OUT_MASK (STEP_MASK | DIR_MASK | (1u << PIN_ENABLE) | (1u << PIN_TICK))
#define IN_MASK ((1u << PIN_ESTOP) | (1u << PIN_ALARM) | (0x1fu << PIN_HOME0))

static struct sb_core core;

/* ---------------------------------------------------------------- clock: 64-bit cycle counter */

static volatile uint32_t g_systick_hi;     /* SysTick wraps every 2^24 cycles (134 ms) */
static uint64_t g_cycle0;                  /* the TIMER's microseconds x 125 when SysTick started */

void isr_systick(void) { g_systick_hi++; }

static uint64_t cycles_now(void)
{
    uint32_t m = irq_save();
    uint32_t hi = g_systick_hi, v = REG(SYST_CVR);
    if (REG(SCB_ICSR) & ICSR_PENDSTSET) {  /* wrapped, its interrupt not yet taken: after the wrap */
        v = REG(SYST_CVR);
        hi++;
    }
    irq_restore(m);
    return g_cycle0 + (((uint64_t)hi << 24) | (0xffffffu - v));
}

static uint64_t now_ns(void) { return cycles_now() * NS_PER_CYCLE; }

/* ---------------------------------------------------------------- UART rings */

#define RX_SIZE 512u
#define TX_SIZE 2048u
static volatile uint8_t g_rx[RX_SIZE];
static volatile uint32_t g_rx_head, g_rx_tail, g_rx_overrun;
static volatile uint32_t g_rx_first_us;    /* TIMER time of the oldest byte not yet given to the core */
static uint8_t g_tx[TX_SIZE];
static uint32_t g_tx_head, g_tx_tail, g_tx_dropped;

void isr_uart0(void)
{
    while (!(REG(UART_FR) & UART_FR_RXFE)) {
        uint8_t b = (uint8_t)REG(UART_DR);
        uint32_t h = g_rx_head, nh = (h + 1u) & (RX_SIZE - 1u);
        if (nh == g_rx_tail) {
            g_rx_overrun++;                /* the main loop fell behind: the host retransmits */
            continue;
        }
        if (h == g_rx_tail)
            g_rx_first_us = REG(TIMER_TIMERAWL);
        g_rx[h] = b;
        g_rx_head = nh;
    }
}

void board_tx(const uint8_t *buf, size_t n)
{
    uint32_t room = (g_tx_tail - g_tx_head - 1u) & (TX_SIZE - 1u), first;
    if (n > room) {                       /* the host is not reading fast enough: the rest is lost */
        g_tx_dropped += (uint32_t)(n - room);
        n = room;
    }
    first = TX_SIZE - g_tx_head < n ? TX_SIZE - g_tx_head : (uint32_t)n;
    memcpy(g_tx + g_tx_head, buf, first);
    memcpy(g_tx, buf + first, n - first);
    g_tx_head = (g_tx_head + (uint32_t)n) & (TX_SIZE - 1u);
}

static void tx_drain(void)
{
    while (g_tx_tail != g_tx_head) {
        uint32_t n = 1, t = g_tx_tail;
        uint32_t fr = REG(UART_FR);
        if (fr & UART_FR_TXFE)
            n = 32;                        /* an empty FIFO takes 32 bytes without asking again */
        else if (fr & UART_FR_TXFF)
            return;
        while (n-- && t != g_tx_head) {
            REG(UART_DR) = g_tx[t];
            t = (t + 1u) & (TX_SIZE - 1u);
        }
        g_tx_tail = t;
    }
}

/* ---------------------------------------------------------------- step, dir, inputs */

/* Per axis, the SysTick value (24 bits, counting down at clk_sys) just after the last STEP and DIR
 * writes: an upper bound of when the pin changed, for the widths below. */
static uint32_t g_last_step[SB_NAXES], g_last_dir[SB_NAXES];
static uint32_t g_old_step, g_old_dir;    /* bit per axis: the last write is long ago (no wait) */

static inline uint32_t systick(void) { return REG(SYST_CVR); }
/* cycles since a SysTick value taken earlier (correct up to 2^24 cycles = 134 ms) */
static inline uint32_t since(uint32_t then) { return (then - systick()) & 0xffffffu; }
static inline uint32_t ns_to_cycles(uint32_t ns) { return (ns + NS_PER_CYCLE - 1u) / NS_PER_CYCLE; }

/* Cycles spent spinning (waiting for an edge's time or a pulse width), not working: the emulator's
 * harness reads this word (--cpu-log) to tell the CPU's work per tick from its waiting. */
volatile uint32_t g_spin_cycles;

static void wait_until(uint64_t t)
{
    uint32_t t0 = systick();
    while (now_ns() < t)
        ;
    g_spin_cycles += since(t0);
}

/* Until `cycles` have passed since the SysTick value `then`; counted as spinning. */
static inline void wait_since(uint32_t then, uint32_t cycles)
{
    uint32_t t0 = systick();
    if (since(then) >= cycles)
        return;
    while (since(then) < cycles)
        ;
    g_spin_cycles += since(t0);
}

/* The core calls this when its poll has passed t_ns (never before). The pin changes now, or later
 * if the last edge of this axis was less than a step width ago (high time before a falling edge,
 * low time before a rising one) or its direction changed less than the set-up time ago. */
void board_step(uint8_t axis, uint8_t level, uint64_t t_ns, uint32_t tick)
{
    uint32_t bit = 1u << axis;
    (void)t_ns;
    (void)tick;
    if (!(g_old_step & bit)) {
        wait_since(g_last_step[axis], ns_to_cycles(core.cfg.step_width_ns));
    }
    if (level) {
        if (!(g_old_dir & bit)) {
            wait_since(g_last_dir[axis], ns_to_cycles(core.cfg.dir_setup_ns));
        }
        REG(SIO_GPIO_OUT_SET) = bit << PIN_STEP0;
    } else {
        REG(SIO_GPIO_OUT_CLR) = bit << PIN_STEP0;
    }
    g_last_step[axis] = systick();
    g_old_step &= ~bit;
}

void board_dir(uint8_t axis, uint8_t dir, uint64_t t_ns, uint32_t tick)
{
    uint32_t bit = 1u << axis;
    (void)t_ns;
    (void)tick;
    /* the core changes DIR at a tick start, after the previous pulse's falling edge: hold it a
     * step width after that edge too */
    if (!(g_old_step & bit))
        wait_since(g_last_step[axis], ns_to_cycles(core.cfg.step_width_ns));
    if (dir)
        REG(SIO_GPIO_OUT_SET) = 1u << (PIN_DIR0 + axis);
    else
        REG(SIO_GPIO_OUT_CLR) = 1u << (PIN_DIR0 + axis);
    g_last_dir[axis] = systick();
    g_old_dir &= ~bit;
}

/* Marks the stamps older than 64 ms as long ago, before they could wrap into a false wait. */
static void age_stamps(void)
{
    int a;
    for (a = 0; a < SB_NAXES; a++) {
        if (since(g_last_step[a]) > (1u << 23))
            g_old_step |= 1u << a;
        if (since(g_last_dir[a]) > (1u << 23))
            g_old_dir |= 1u << a;
    }
}

void board_tick_start(uint32_t tick, uint64_t t_ns)
{
    (void)tick;
    (void)t_ns;
    REG(SIO_GPIO_OUT_XOR) = 1u << PIN_TICK;             /* toggle the strobe */
}

static uint16_t g_home_prev;
static int g_home_known;

uint16_t board_inputs(void)
{
    uint32_t in = REG(SIO_GPIO_IN);
    uint16_t v = 0;
    int a;
    if (in & (1u << PIN_ESTOP))
        v |= SB_IN_ESTOP;
    if (!(in & (1u << PIN_ALARM)))
        v |= SB_IN_ALARM_ALL;
    for (a = 0; a < SB_NAXES; a++)
        if (!(in & (1u << (PIN_HOME0 + a))))
            v |= SB_IN_HOME(a);
    /* a home switch that changed since the last poll: latched at this poll's time (the error is the
     * loop's latency times the step rate; the loop polls at every edge while stepping) */
    if (g_home_known) {
        uint16_t ch = (uint16_t)((v ^ g_home_prev) & 0x1fu);
        for (a = 0; a < SB_NAXES; a++)
            if (ch & SB_IN_HOME(a))
                sb_home_edge(&core, (uint8_t)a, (uint8_t)!!(v & SB_IN_HOME(a)), core.now);
    }
    g_home_prev = v;
    g_home_known = 1;
    return v;
}

static int16_t g_adc[SB_NADC];
static uint32_t g_adc_ch;

static void adc_service(void)
{
    uint32_t cs = REG(ADC_CS);
    if (!(cs & ADC_CS_READY))
        return;
    g_adc[g_adc_ch] = (int16_t)(REG(ADC_RESULT) & 0xfffu);
    g_adc_ch = (g_adc_ch + 1u) % SB_NADC;
    REG(ADC_CS) = ADC_CS_EN | ((ADC_CH0 + g_adc_ch) << ADC_CS_AINSEL_SHIFT) | ADC_CS_START_ONCE;
}

void board_adc(int16_t out[3]) { memcpy(out, g_adc, sizeof g_adc); }

void board_event(const char *what, const struct sb_core *c)
{
    (void)what;
    /* the drives are enabled while the bridge is armed and not faulted */
    if (c->state == SB_S_FAULT || c->state == SB_S_IDLE)
        REG(SIO_GPIO_OUT_CLR) = 1u << PIN_ENABLE;
    else
        REG(SIO_GPIO_OUT_SET) = 1u << PIN_ENABLE;
}

/* ---------------------------------------------------------------- wake-ups */

void isr_timer0(void) { REG(TIMER_INTR) = 1u; }

static volatile uint32_t g_input_irq;     /* an input pin changed: poll the core now */

void isr_io_bank0(void)
{
    int i;
    g_input_irq = 1;
    for (i = 0; i < 4; i++)                /* clear the edge events; the main loop reads the pins */
        REG(IO_BANK0_BASE + 0xf0u + 4u * (uint32_t)i) = 0xffffffffu;
}

/* Received bytes go to the core in batches (a UART interrupt comes with each byte, in the emulator
 * at least): when a frame's worth is there or the oldest has waited RX_WAIT_US, and it has waited
 * at least min_age_us. */
static int rx_due(uint32_t min_age_us)
{
    uint32_t n = (g_rx_head - g_rx_tail) & (RX_SIZE - 1u), age;
    if (!n)
        return 0;
    age = REG(TIMER_TIMERAWL) - g_rx_first_us;
    return (n >= RX_BATCH || age >= RX_WAIT_US) && age >= min_age_us;
}

/* Sleeps until about t (ns), or until a byte or an input edge arrives. */
static void sleep_until(uint64_t t)
{
    uint64_t now = now_ns();
    uint32_t us;
    uint32_t m;
    if (t <= now + SPIN_NS)
        return;
    us = (t - now > 100000000u) ? 100000u : (uint32_t)(t - now) / 1000u;
    us -= 2u;                              /* wake early; the rest is spun */
    /* armed with interrupts masked: an alarm (or a byte) that comes before the WFI stays pending and
     * ends the WFI at once, instead of being taken before it and leaving the loop asleep */
    m = irq_save();
    REG(TIMER_ALARM0) = REG(TIMER_TIMERAWL) + us;
    if (((g_rx_head - g_rx_tail) & (RX_SIZE - 1u)) < RX_BATCH && !g_input_irq)
        wfi();                             /* a pending interrupt ends WFI even with PRIMASK set */
    irq_restore(m);
}

/* ---------------------------------------------------------------- the hardware divider */

/* The compiler's 32-bit unsigned division helpers on the SIO divider (8 cycles instead of a
 * software loop): the core divides at every tick start. Only the main loop divides; no interrupt
 * handler does, so the divider's state is never shared. */
static inline void hwdiv(uint32_t a, uint32_t b)
{
    REG(SIO_DIV_UDIVIDEND) = a;
    REG(SIO_DIV_UDIVISOR) = b;
    while (!(REG(SIO_DIV_CSR) & 1u))       /* READY after 8 cycles */
        ;
}

uint32_t __aeabi_uidiv(uint32_t a, uint32_t b);
uint64_t __aeabi_uidivmod(uint32_t a, uint32_t b);

uint32_t __aeabi_uidiv(uint32_t a, uint32_t b)
{
    hwdiv(a, b);
    return REG(SIO_DIV_QUOTIENT);
}

uint64_t __aeabi_uidivmod(uint32_t a, uint32_t b)     /* quotient in r0, remainder in r1 */
{
    uint32_t r;
    hwdiv(a, b);
    r = REG(SIO_DIV_REMAINDER);
    return REG(SIO_DIV_QUOTIENT) | ((uint64_t)r << 32);
}

/* ---------------------------------------------------------------- set-up */

static void unreset(uint32_t bits)
{
    REG_CLR(RESETS_RESET) = bits;
    while ((REG(RESETS_RESET_DONE) & bits) != bits)
        ;
}

static void pll_init(uint32_t base, uint32_t fbdiv, uint32_t pd1, uint32_t pd2)
{
    REG(base + PLL_PWR) = 0xffffffffu;     /* powered down while configured */
    REG(base + PLL_FBDIV_INT) = 0;
    REG(base + PLL_CS) = 1u;               /* REFDIV = 1: 12 MHz reference */
    REG(base + PLL_FBDIV_INT) = fbdiv;
    REG_CLR(base + PLL_PWR) = PLL_PWR_PD | PLL_PWR_VCOPD;
    while (!(REG(base + PLL_CS) & PLL_CS_LOCK))
        ;
    REG(base + PLL_PRIM) = (pd1 << 16) | (pd2 << 12);
    REG_CLR(base + PLL_PWR) = PLL_PWR_POSTDIVPD;
}

static void clocks_init(void)
{
    REG(CLK_SYS_RESUS_CTRL) = 0;
    REG(XOSC_CTRL) = XOSC_CTRL_FREQ_1_15MHZ;
    REG(XOSC_STARTUP) = 47u;               /* ~1 ms at 12 MHz: (12e6 / 1000 + 128) / 256 */
    REG(XOSC_CTRL) = XOSC_CTRL_FREQ_1_15MHZ | XOSC_CTRL_ENABLE;
    while (!(REG(XOSC_STATUS) & XOSC_STATUS_STABLE))
        ;
    REG_CLR(CLK_SYS_CTRL) = 1u;            /* clk_sys from clk_ref while the PLL is set up */
    while (REG(CLK_SYS_SELECTED) != 1u)
        ;
    REG(CLK_REF_CTRL) = CLK_REF_SRC_XOSC;
    while (REG(CLK_REF_SELECTED) != (1u << CLK_REF_SRC_XOSC))
        ;
    REG(CLK_REF_DIV) = 1u << 8;
    REG_SET(RESETS_RESET) = RESET_PLL_SYS | RESET_PLL_USB;
    unreset(RESET_PLL_SYS | RESET_PLL_USB);
    pll_init(PLL_SYS_BASE, 125u, 6u, 2u);  /* 12 MHz x 125 = 1500 MHz VCO / 6 / 2 = 125 MHz */
    pll_init(PLL_USB_BASE, 100u, 5u, 5u);  /* 12 MHz x 100 = 1200 MHz VCO / 5 / 5 = 48 MHz */
    REG(CLK_SYS_DIV) = 1u << 8;
    REG(CLK_SYS_CTRL) = CLK_SYS_AUXSRC_PLL_SYS;            /* aux = pll_sys, still on clk_ref */
    REG(CLK_SYS_CTRL) = CLK_SYS_AUXSRC_PLL_SYS | CLK_SYS_SRC_AUX;
    while (REG(CLK_SYS_SELECTED) != 2u)
        ;
    REG(CLK_PERI_CTRL) = 0;
    REG(CLK_PERI_CTRL) = CLK_CTRL_ENABLE | CLK_PERI_AUXSRC_CLK_SYS;
    REG(CLK_ADC_CTRL) = 0;
    REG(CLK_ADC_DIV) = 1u << 8;
    REG(CLK_ADC_CTRL) = CLK_CTRL_ENABLE | CLK_ADC_AUXSRC_PLL_USB;
    /* the watchdog's tick generator makes the TIMER's 1 us from clk_ref (12 MHz / 12) */
    REG(WATCHDOG_TICK) = WATCHDOG_TICK_ENABLE | 12u;
}

static void gpio_init(void)
{
    uint32_t n;
    REG(SIO_GPIO_OUT_CLR) = OUT_MASK;
    REG(SIO_GPIO_OUT_SET) = DIR_MASK;      /* direction + : what the core assumes at start */
    REG(SIO_GPIO_OE_SET) = OUT_MASK;
    for (n = 0; n < 30; n++) {
        if (OUT_MASK & (1u << n)) {
            REG(PADS_GPIO(n)) = PADS_DRIVE_8MA | PADS_SLEWFAST;
            REG(GPIO_CTRL(n)) = GPIO_FUNC_SIO;
        } else if (IN_MASK & (1u << n)) {
            REG(PADS_GPIO(n)) = PADS_IE | PADS_PUE | PADS_SCHMITT;
            REG(GPIO_CTRL(n)) = GPIO_FUNC_SIO;
            /* PROC0_INTE: edge low (bit 2) and edge high (bit 3) of this pin: wake the loop */
            REG_SET(IO_BANK0_BASE + 0x100u + 4u * (n / 8u)) = 0xcu << (4u * (n % 8u));
        }
    }
    REG(PADS_GPIO(PIN_UART_TX)) = PADS_DRIVE_8MA;
    REG(PADS_GPIO(PIN_UART_RX)) = PADS_IE | PADS_PUE | PADS_SCHMITT;
    REG(GPIO_CTRL(PIN_UART_TX)) = GPIO_FUNC_UART;
    REG(GPIO_CTRL(PIN_UART_RX)) = GPIO_FUNC_UART;
    for (n = 26; n < 29; n++)              /* ADC inputs: digital input and pulls off */
        REG(PADS_GPIO(n)) = PADS_OD;
}

static void uart_init(void)
{
    /* divisor = clk_peri / (16 baud) = 2.604: IBRD 2, FBRD round(0.604 x 64) = 39 -> 2.994 Mbaud */
    uint32_t div64 = (8u * CLK_SYS_HZ / UART_BAUD + 1u) / 2u;    /* 64 x 16 x divisor / 16, rounded */
    REG(UART_IBRD) = div64 >> 6;
    REG(UART_FBRD) = div64 & 0x3fu;
    REG(UART_LCR_H) = UART_LCR_H_WLEN8 | UART_LCR_H_FEN;        /* also latches the divisor */
    REG(UART_CR) = UART_CR_UARTEN | UART_CR_TXE | UART_CR_RXE;
    REG(UART_IFLS) = 0;                    /* RX interrupt at 1/8 full (4 bytes), or the timeout */
    REG(UART_IMSC) = UART_IMSC_RXIM | UART_IMSC_RTIM;
}

static void watchdog_init(void)
{
    REG(PSM_WDSEL) = 0x1fffcu;             /* a watchdog reset resets everything but the oscillators */
    REG(WATCHDOG_LOAD) = 2u * WDOG_US;     /* the counter decrements twice per tick (erratum RP2040-E1) */
    REG(WATCHDOG_CTRL) = WATCHDOG_CTRL_ENABLE | WATCHDOG_CTRL_PAUSE_DBG;
}

static uint32_t g_fed_us;

/* Fed once a millisecond at most: the loop passes here at every edge. */
static inline void watchdog_feed(void)
{
    uint32_t t = REG(TIMER_TIMERAWL);
    if (t - g_fed_us >= 1000u) {
        REG(WATCHDOG_LOAD) = 2u * WDOG_US;
        g_fed_us = t;
    }
}

int main(void)
{
    uint8_t buf[RX_CHUNK];
    REG_SET(RESETS_RESET) = RESET_IO_BANK0 | RESET_PADS_BANK0 | RESET_UART0 | RESET_TIMER | RESET_ADC;
    clocks_init();
    unreset(RESET_IO_BANK0 | RESET_PADS_BANK0 | RESET_UART0 | RESET_TIMER | RESET_ADC);
    gpio_init();
    uart_init();
    REG(ADC_CS) = ADC_CS_EN | (ADC_CH0 << ADC_CS_AINSEL_SHIFT) | ADC_CS_START_ONCE;
    REG(SYST_RVR) = 0xffffffu;
    REG(SYST_CVR) = 0;
    REG(SYST_CSR) = 7u;                    /* clk_sys, interrupt at the wrap, enabled */
    REG(SCB_ICSR) = ICSR_PENDSTCLR;        /* (the emulator counts the write of CVR as a wrap) */
    g_systick_hi = 0;
    /* the clock starts at the TIMER's time (within 1 us): STATUS times are the TIMER's microseconds */
    g_cycle0 = (uint64_t)REG(TIMER_TIMERAWL) * (CLK_SYS_HZ / 1000000u) - (0xffffffu - REG(SYST_CVR));
    REG(TIMER_INTE) = 1u;                  /* alarm 0 wakes the loop */
    REG(NVIC_ICPR) = 0xffffffffu;
    REG(NVIC_ISER) = (1u << IRQ_TIMER_0) | (1u << 13) | (1u << IRQ_UART0);
    watchdog_init();
    sb_init(&core, now_ns());
    irq_enable();
    for (;;) {
        uint64_t dl, edge, now;
        uint32_t n = 0;
        watchdog_feed();
        dl = sb_next_deadline(&core);      /* tick boundary, watchdog, idle status */
        edge = sb_next_edge(&core);
        now = now_ns();
        if (g_input_irq) {                 /* an input changed: no edge after this one (E-stop, alarm) */
            g_input_irq = 0;
            sb_poll(&core, core.now);      /* at the time of the last edge emitted: none newer goes out */
            continue;
        }
        if (now >= dl) {                   /* a deadline passed: tick boundary, watchdog, idle status */
            sb_poll(&core, now);
            continue;
        }
        if (edge <= now + SPIN_NS) {       /* step edges: emit them as they come due */
            if (now > edge + LATE_NS) {    /* more steps than this chip can time: a controlled stop */
                sb_board_fault(&core, SB_F_LATE);
                continue;
            }
            wait_until(edge);
            now = now_ns();
            edge = sb_advance(&core, now);
            if (g_tx_tail != g_tx_head)
                tx_drain();
            /* received bytes are taken between edges; while the edges come closer than SPIN_NS,
             * once the oldest has waited 2 x RX_WAIT_US: the link is never starved (the edges are
             * then late, never shorter: board_step) */
            if (!rx_due(edge <= now + SPIN_NS ? 2u * RX_WAIT_US : 0u))
                continue;
        }
        if (rx_due(0)) {
            while (n < RX_CHUNK && g_rx_tail != g_rx_head) {
                buf[n++] = g_rx[g_rx_tail];
                g_rx_tail = (g_rx_tail + 1u) & (RX_SIZE - 1u);
            }
            if (g_rx_tail != g_rx_head)
                g_rx_first_us = REG(TIMER_TIMERAWL);
            sb_rx(&core, buf, n, now);
            continue;
        }
        tx_drain();
        adc_service();
        age_stamps();
        if (g_tx_tail != g_tx_head)
            continue;                      /* the FIFO is full: keep draining */
        if (dl <= now + SPIN_NS) {
            wait_until(dl);
            continue;
        }
        if (edge < dl)
            dl = edge;
        if (g_rx_tail != g_rx_head && dl > now + 1000u * (RX_WAIT_US + 2u))
            dl = now + 1000u * (RX_WAIT_US + 2u);  /* the oldest byte's wait */
        sleep_until(dl);
    }
}
