/* The DAQ-1 firmware core on the host, served on a pseudo terminal (for the tests).
 *
 *   daq1-host [--serial S] [--rates R1[,R2...]] [--lose-row N]
 *
 * --rates: the board's sample rates (the first is the *RST rate; default 1000);
 * --lose-row: the ADC loses conversion N after every start (to test what the core does then).
 * prints "daq: /dev/pts/N" and serves until SIGINT/SIGTERM. */
#define _XOPEN_SOURCE 700
#define _DEFAULT_SOURCE   /* cfmakeraw */
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#include "../core/daq1.h"
#include "host_hal.h"

#define MAX_RATES 16

static daq1 instrument;
static volatile sig_atomic_t stop;

static void on_signal(int sig)
{
    (void)sig;
    stop = 1;
}

static int usage(const char *why)
{
    fprintf(stderr, "daq1-host: %s\nusage: daq1-host [--serial S] [--rates R1[,R2...]]\n", why);
    return 2;
}

static int parse_rates(char *text, double *rates)
{
    int n = 0;
    for (char *item = strtok(text, ","); item; item = strtok(NULL, ",")) {
        char *end;
        double rate = strtod(item, &end);
        if (*end || !(rate > 0) || n == MAX_RATES)
            return 0;
        rates[n++] = rate;
    }
    return n;
}

/* A raw pty; the slave stays open here too, so the master never sees a hang-up between hosts. */
static int open_pty(int *slave)
{
    struct termios raw;
    int master = posix_openpt(O_RDWR | O_NOCTTY);
    if (master < 0 || grantpt(master) || unlockpt(master))
        return -1;
    *slave = open(ptsname(master), O_RDWR | O_NOCTTY);
    if (*slave < 0 || tcgetattr(*slave, &raw))
        return -1;
    cfmakeraw(&raw);
    if (tcsetattr(*slave, TCSANOW, &raw))
        return -1;
    fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
    return master;
}

int main(int argc, char **argv)
{
    static double rates[MAX_RATES] = {1000.0};
    host_options options = {"host", rates, 1, -1};
    int slave;
    for (int i = 1; i < argc; i++) {
        char *end;
        if (!strcmp(argv[i], "--serial") && i + 1 < argc) {
            options.serial = argv[++i];
        } else if (!strcmp(argv[i], "--rates") && i + 1 < argc) {
            if (!(options.n_rates = parse_rates(argv[++i], rates)))
                return usage("--rates: a comma-separated list of positive numbers (at most 16)");
        } else if (!strcmp(argv[i], "--lose-row") && i + 1 < argc) {
            options.lose_row = strtol(argv[++i], &end, 10);
            if (*end || options.lose_row < 0)
                return usage("--lose-row: a row number >= 0");
        } else {
            return usage(argv[i]);
        }
    }
    int master = open_pty(&slave);
    if (master < 0) {
        fprintf(stderr, "daq1-host: cannot open a pseudo terminal: %s\n", strerror(errno));
        return 1;
    }
    host_hal_setup(&options, master);
    daq1_init(&instrument, hal_board_info());
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    printf("daq: %s\n", ptsname(master));
    fflush(stdout);

    uint8_t input[512];
    size_t have = 0, used = 0;
    while (!stop) {
        /* wait for input the core takes, room for its output, or the next conversions (1 ms) */
        struct pollfd p = {master, 0, 0};
        if (used == have && daq1_accepts_input(&instrument))
            p.events |= POLLIN;
        if (daq1_output_pending(&instrument))
            p.events |= POLLOUT;
        if (poll(&p, 1, daq1_acquiring(&instrument) ? 1 : 100) > 0 && (p.revents & POLLIN)) {
            ssize_t got = read(master, input, sizeof input);
            have = got > 0 ? (size_t)got : 0;
            used = 0;
        }
        if (used < have)
            used += daq1_receive(&instrument, input + used, have - used);
        daq1_poll(&instrument);
    }
    close(master);
    close(slave);
    return 0;
}
