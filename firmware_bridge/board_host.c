/* board_host.c - the host board layer: runs the portable core as a Linux process on a pty.
 *
 *   bridge-host [--link-file PATH] [--edge-log PATH] [--control PATH] [--orphan-exit-ms N]
 *               [--rt-priority N] [--home-at AXIS:PULSES]... [--quiet]
 *
 * - Opens a pseudo-terminal (posix_openpt) and prints "PTY <slave path>" on stdout (and writes
 *   the path to --link-file); the host opens the slave as its serial port. The bridge keeps a
 *   slave descriptor open itself, so a host that goes away looks like a silent line (as a UART
 *   does), not an error: the watchdog must notice.
 * - Clock: CLOCK_MONOTONIC in ns (the same clock as Python's time.monotonic_ns()).
 * - --edge-log: every step edge, direction change and tick start as a 16-byte little-endian
 *   record: u64 t_ns, u32 tick, u8 axis (255 = tick start), u8 kind (0 step low, 1 step high,
 *   2 dir -, 3 dir +, 4 tick start), u16 0. The timestamps are the ones the step generator
 *   computed: this build has no pins; it proves the arithmetic, not electrical timing.
 * - --control: a FIFO (created if missing) taking text lines that set the simulated inputs:
 *   "estop 0|1", "alarm AXIS 0|1", "home AXIS 0|1", "adc CH COUNTS", "quit".
 *   The strain ADC channels read what was last set there (0 by default): no strain model.
 * - --home-at AXIS:PULSES (repeatable): a simulated home switch on AXIS (0-4 = L1 L2 L3 X Y) that
 *   is closed while the motor is at or past PULSES. The motor position is the counters of the
 *   first RESET (the controller's counters at start) plus every step emitted since: a later RESET
 *   re-references the counters, it does not move the motor. The switch is evaluated at every step
 *   edge and its transitions go to sb_home_edge() with the edge's time, so the latch is exact.
 *   "home AXIS 0|1" on --control sets a switch by hand (latched at the time the line is read).
 * - --rt-priority N: asks for SCHED_FIFO priority N (a board has the CPU to itself; a process
 *   shares it), and runs at normal priority with a note on stderr when that is not permitted.
 * - Exits on SIGTERM/SIGINT, on "quit", or --orphan-exit-ms after its parent process died
 *   (default 2000 ms: long enough for the watchdog to act and report).
 */
#define _GNU_SOURCE             /* ppoll, posix_openpt: this layer is Linux-only by design */

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <sched.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "board.h"
#include "core.h"

const char board_name[] = "host-pty";

static int g_master = -1;
static FILE *g_edges;
static int g_quiet;
static uint16_t g_inputs;
static int16_t g_adc[SB_NADC];
static unsigned long g_tx_dropped;
static volatile sig_atomic_t g_stop;
static struct sb_core core;
/* simulated home switches (--home-at) */
static uint8_t g_home_sim;             /* bit per axis: a simulated switch is configured */
static int64_t g_home_at[SB_NAXES];
static int64_t g_motor[SB_NAXES];      /* motor position, steps (known after the first RESET) */
static int g_motor_known;
static int8_t g_motor_dir[SB_NAXES] = {1, 1, 1, 1, 1};

static void home_sim_update(uint8_t axis, uint64_t t, int latch)
{
    uint16_t bit = (uint16_t)SB_IN_HOME(axis);
    int closed = g_motor[axis] >= g_home_at[axis];
    if (!(g_home_sim & (1u << axis)) || closed == !!(g_inputs & bit))
        return;
    g_inputs = (uint16_t)(closed ? (g_inputs | bit) : (g_inputs & ~bit));
    if (latch)
        sb_home_edge(&core, axis, (uint8_t)closed, t);
}

static uint64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

static void edge(uint64_t t, uint32_t tick, uint8_t axis, uint8_t kind)
{
    uint8_t r[16];
    int i;
    if (!g_edges)
        return;
    for (i = 0; i < 8; i++)
        r[i] = (uint8_t)(t >> (8 * i));
    sb_put_u32(r + 8, tick);
    r[12] = axis;
    r[13] = kind;
    r[14] = r[15] = 0;
    fwrite(r, 1, sizeof r, g_edges);
}

void board_step(uint8_t axis, uint8_t level, uint64_t t_ns, uint32_t tick)
{
    edge(t_ns, tick, axis, level);
    if (level && g_motor_known && axis < SB_NAXES) {
        g_motor[axis] += g_motor_dir[axis];
        home_sim_update(axis, t_ns, 1);
    }
}

void board_dir(uint8_t axis, uint8_t dir, uint64_t t_ns, uint32_t tick)
{
    edge(t_ns, tick, axis, (uint8_t)(dir ? 3 : 2));
    if (axis < SB_NAXES)
        g_motor_dir[axis] = (int8_t)(dir ? 1 : -1);
}

void board_tick_start(uint32_t tick, uint64_t t_ns) { edge(t_ns, tick, 255, 4); }
uint16_t board_inputs(void) { return g_inputs; }
void board_adc(int16_t out[3]) { memcpy(out, g_adc, sizeof g_adc); }

void board_tx(const uint8_t *buf, size_t n)
{
    size_t off = 0;
    while (off < n) {
        ssize_t w = write(g_master, buf + off, n - off);
        if (w > 0) {
            off += (size_t)w;
            continue;
        }
        if (w < 0 && errno == EINTR)
            continue;
        /* nobody reading (the pty buffer is full): the rest of the frame is lost, as on a UART
         * with no listener; the host's parser resynchronises on the next frame */
        g_tx_dropped += n - off;
        return;
    }
}

void board_event(const char *what, const struct sb_core *c)
{
    int i;
    if (!g_motor_known && !strcmp(what, "reset")) {
        /* the first RESET places the simulated motors: the controller's counters at start */
        g_motor_known = 1;
        for (i = 0; i < SB_NAXES; i++) {
            g_motor[i] = c->counters[i];
            home_sim_update((uint8_t)i, c->now, 0);
        }
    }
    if (g_edges)
        fflush(g_edges);
    if (g_quiet)
        return;
    fprintf(stderr, "bridge: %s t=%llu state=%d faults=0x%02x inputs=0x%04x started=%lu done=%lu "
            "counters=%ld,%ld,%ld,%ld,%ld not_executed=%ld,%ld,%ld,%ld,%ld dropped_ticks=%lu "
            "last_tick_rx=%llu\n", what, (unsigned long long)c->now, c->state, c->faults, c->inputs,
            (unsigned long)c->started, (unsigned long)c->done,
            (long)c->counters[0], (long)c->counters[1], (long)c->counters[2], (long)c->counters[3],
            (long)c->counters[4], (long)c->not_executed[0], (long)c->not_executed[1],
            (long)c->not_executed[2], (long)c->not_executed[3], (long)c->not_executed[4],
            (unsigned long)c->dropped_ticks, (unsigned long long)c->last_tick_rx);
    fflush(stderr);
}

static void on_signal(int sig)
{
    (void)sig;
    g_stop = 1;
}

static void set_raw(int fd)
{
    struct termios t;
    if (tcgetattr(fd, &t) != 0)
        return;
    t.c_iflag &= ~(tcflag_t)(IGNBRK | BRKINT | PARMRK | ISTRIP | INLCR | IGNCR | ICRNL | IXON | IXOFF);
    t.c_oflag &= ~(tcflag_t)OPOST;
    t.c_lflag &= ~(tcflag_t)(ECHO | ECHONL | ICANON | ISIG | IEXTEN);
    t.c_cflag &= ~(tcflag_t)(CSIZE | PARENB);
    t.c_cflag |= CS8;
    t.c_cc[VMIN] = 1;
    t.c_cc[VTIME] = 0;
    tcsetattr(fd, TCSANOW, &t);
}

/* One control line; returns 1 on "quit". */
static int control_line(char *s)
{
    int a = -1, v = 0;
    char cmd[16];
    if (sscanf(s, "%15s", cmd) != 1)
        return 0;
    if (!strcmp(cmd, "quit"))
        return 1;
    if (!strcmp(cmd, "estop") && sscanf(s, "%*s %d", &v) == 1) {
        g_inputs = (uint16_t)(v ? (g_inputs | SB_IN_ESTOP) : (g_inputs & ~SB_IN_ESTOP));
    } else if (!strcmp(cmd, "alarm") && sscanf(s, "%*s %d %d", &a, &v) == 2 && a >= 0 && a < SB_NAXES) {
        g_inputs = (uint16_t)(v ? (g_inputs | SB_IN_ALARM(a)) : (g_inputs & ~SB_IN_ALARM(a)));
    } else if (!strcmp(cmd, "home") && sscanf(s, "%*s %d %d", &a, &v) == 2 && a >= 0 && a < SB_NAXES) {
        if (!!(g_inputs & SB_IN_HOME(a)) != !!v)
            sb_home_edge(&core, (uint8_t)a, (uint8_t)!!v, core.now);
        g_inputs = (uint16_t)(v ? (g_inputs | SB_IN_HOME(a)) : (g_inputs & ~SB_IN_HOME(a)));
    } else if (!strcmp(cmd, "adc") && sscanf(s, "%*s %d %d", &a, &v) == 2 && a >= 0 && a < SB_NADC) {
        g_adc[a] = (int16_t)v;
    } else if (!g_quiet) {
        fprintf(stderr, "bridge: control: ignored line '%s'\n", s);
    }
    return 0;
}

static void usage(void)
{
    fprintf(stderr, "usage: bridge-host [--link-file PATH] [--edge-log PATH] [--control FIFO] "
                    "[--orphan-exit-ms N] [--rt-priority N] [--home-at AXIS:PULSES]... [--quiet]\n");
    exit(2);
}

int main(int argc, char **argv)
{
    const char *link_file = NULL, *edge_path = NULL, *control_path = NULL;
    long orphan_ms = 2000, rt_prio = 0;
    int slave, ctl = -1, i;
    char *name;
    char cbuf[512];
    size_t cn = 0;
    pid_t ppid = getppid();
    uint64_t exit_at = UINT64_MAX;
    struct sigaction sa;

    for (i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--link-file") && i + 1 < argc)
            link_file = argv[++i];
        else if (!strcmp(argv[i], "--edge-log") && i + 1 < argc)
            edge_path = argv[++i];
        else if (!strcmp(argv[i], "--control") && i + 1 < argc)
            control_path = argv[++i];
        else if (!strcmp(argv[i], "--orphan-exit-ms") && i + 1 < argc)
            orphan_ms = strtol(argv[++i], NULL, 10);
        else if (!strcmp(argv[i], "--rt-priority") && i + 1 < argc)
            rt_prio = strtol(argv[++i], NULL, 10);
        else if (!strcmp(argv[i], "--home-at") && i + 1 < argc) {
            char *end;
            long ax = strtol(argv[++i], &end, 10);
            long long at;
            if (*end != ':' || ax < 0 || ax >= SB_NAXES)
                usage();
            at = strtoll(end + 1, &end, 10);
            if (*end)
                usage();
            g_home_sim = (uint8_t)(g_home_sim | (1u << ax));
            g_home_at[ax] = at;
        } else if (!strcmp(argv[i], "--quiet"))
            g_quiet = 1;
        else
            usage();
    }
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);

    if (rt_prio > 0) {
        struct sched_param sp;
        memset(&sp, 0, sizeof sp);
        sp.sched_priority = (int)rt_prio;
        if (sched_setscheduler(0, SCHED_FIFO, &sp) != 0 && !g_quiet)
            fprintf(stderr, "bridge: SCHED_FIFO %ld not permitted (%s): normal priority\n", rt_prio, strerror(errno));
    }
    g_master = posix_openpt(O_RDWR | O_NOCTTY);
    if (g_master < 0 || grantpt(g_master) != 0 || unlockpt(g_master) != 0 || !(name = ptsname(g_master))) {
        perror("bridge: posix_openpt");
        return 1;
    }
    slave = open(name, O_RDWR | O_NOCTTY);
    if (slave < 0) {
        perror("bridge: open pty slave");
        return 1;
    }
    set_raw(slave);
    fcntl(g_master, F_SETFL, fcntl(g_master, F_GETFL) | O_NONBLOCK);
    if (edge_path) {
        g_edges = fopen(edge_path, "wb");
        if (!g_edges) {
            perror("bridge: --edge-log");
            return 1;
        }
        setvbuf(g_edges, NULL, _IOFBF, 1 << 20);
    }
    if (control_path) {
        if (mkfifo(control_path, 0600) != 0 && errno != EEXIST) {
            perror("bridge: --control mkfifo");
            return 1;
        }
        ctl = open(control_path, O_RDWR | O_NONBLOCK);   /* RDWR: no EOF when writers come and go */
        if (ctl < 0) {
            perror("bridge: --control open");
            return 1;
        }
    }
    if (link_file) {
        FILE *f = fopen(link_file, "w");
        if (!f || fprintf(f, "%s\n", name) < 0 || fclose(f) != 0) {
            perror("bridge: --link-file");
            return 1;
        }
    }
    printf("PTY %s\n", name);
    fflush(stdout);

    sb_init(&core, now_ns());
    while (!g_stop) {
        struct pollfd pf[2];
        struct timespec to;
        uint64_t t = now_ns(), dl = sb_next_deadline(&core), wait;
        int nf = 1, r;
        if (t >= exit_at)
            break;
        if (getppid() != ppid && exit_at == UINT64_MAX)
            exit_at = t + (uint64_t)orphan_ms * 1000000u;
        wait = dl > t ? dl - t : 0;
        if (wait > 10000000u)
            wait = 10000000u;      /* wake at least every 10 ms (parent check) */
        to.tv_sec = (time_t)(wait / 1000000000u);
        to.tv_nsec = (long)(wait % 1000000000u);
        pf[0].fd = g_master;
        pf[0].events = POLLIN;
        if (ctl >= 0) {
            pf[1].fd = ctl;
            pf[1].events = POLLIN;
            nf = 2;
        }
        r = ppoll(pf, (nfds_t)nf, &to, NULL);
        if (r < 0 && errno != EINTR) {
            perror("bridge: ppoll");
            break;
        }
        if (r > 0 && (pf[0].revents & POLLIN)) {
            uint8_t buf[4096];
            ssize_t n;
            while ((n = read(g_master, buf, sizeof buf)) > 0)
                sb_rx(&core, buf, (uint32_t)n, now_ns());
        }
        if (r > 0 && nf == 2 && (pf[1].revents & POLLIN)) {
            ssize_t n = read(ctl, cbuf + cn, sizeof cbuf - 1 - cn);
            if (n > 0) {
                char *nl;
                cn += (size_t)n;
                cbuf[cn] = 0;
                while ((nl = strchr(cbuf, '\n'))) {
                    *nl = 0;
                    if (control_line(cbuf))
                        g_stop = 1;
                    memmove(cbuf, nl + 1, cn - (size_t)(nl + 1 - cbuf) + 1);
                    cn -= (size_t)(nl + 1 - cbuf);
                }
                if (cn >= sizeof cbuf - 1)
                    cn = 0;          /* an overlong line: dropped */
            }
        }
        sb_poll(&core, now_ns());
        if (g_edges && core.state != SB_S_RUNNING && core.state != SB_S_DRAINING)
            fflush(g_edges);         /* not stepping: the log on disk is complete */
    }
    board_event("exit", &core);
    if (g_edges)
        fclose(g_edges);
    if (g_tx_dropped && !g_quiet)
        fprintf(stderr, "bridge: %lu bytes to the host dropped (nobody reading)\n", g_tx_dropped);
    close(slave);
    close(g_master);
    return 0;
}
