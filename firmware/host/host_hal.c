/* Host board for the tests: a deterministic test signal paced by the monotonic clock, and a pty link.
 *
 * Channels as the test rig double (tests/rig_double.py): force (N, LSB 1e-4), acc:x1 and acc:x2 (m/s^2,
 * LSB 1e-3), one ADC code = one count at the *RST sensitivity. Row k (from hal_adc_start) of channel c is
 *   signature(k, c) + triangle(k),
 * signature as in tests/rig_double.py, triangle a +-20000 code wave of period 400 samples: exact integers,
 * so the tests compare every delivered sample with the truth. */
#define _POSIX_C_SOURCE 200809L
#include "host_hal.h"

#include "../core/daq1.h"

#include <errno.h>
#include <time.h>
#include <unistd.h>

#define CHANNELS 3
#define TRIANGLE_AMPLITUDE 20000
#define TRIANGLE_PERIOD 400

static const hal_channel HOST_CHANNELS[CHANNELS] = {
    {"force", "N", 1e-4, 0.01 * 1e-4, (1 << 23) - 1},
    {"acc:x1", "m/s^2", 1e-3, 0.01 * 1e-3, (1 << 23) - 1},
    {"acc:x2", "m/s^2", 1e-3, 0.01 * 1e-3, (1 << 23) - 1},
};

typedef char channels_fit_the_core[CHANNELS <= DAQ1_MAX_CHANNELS ? 1 : -1];

static hal_board board = {"host", HOST_CHANNELS, CHANNELS, 0, 0};
static int link_fd = -1;
static long lose_row = -1;
static double adc_rate;
static int adc_running;
static int64_t adc_rows;
static struct timespec adc_start;

void host_hal_setup(const host_options *options, int fd)
{
    board.serial = options->serial;
    board.rates = options->rates;
    board.n_rates = options->n_rates;
    lose_row = options->lose_row;
    link_fd = fd;
}

const hal_board *hal_board_info(void) { return &board; }

int32_t host_signal(int64_t k, int channel)
{
    int64_t mixed = (k * 2654435761LL + 97531LL * (channel + 1)) % 1000003LL;
    int64_t signature = mixed % 101 - 50;
    int64_t phase = k % TRIANGLE_PERIOD;
    int64_t triangle = (phase * 4 * TRIANGLE_AMPLITUDE / TRIANGLE_PERIOD) - 2 * TRIANGLE_AMPLITUDE;
    triangle = (triangle < 0 ? -triangle : triangle) - TRIANGLE_AMPLITUDE;
    return (int32_t)(signature + triangle);
}

void hal_adc_start(double rate)
{
    adc_rate = rate;
    adc_rows = 0;
    adc_running = 1;
    clock_gettime(CLOCK_MONOTONIC, &adc_start);
}

void hal_adc_stop(void) { adc_running = 0; }

int hal_adc_read(int32_t *codes)
{
    struct timespec now;
    if (!adc_running)
        return HAL_ADC_NONE;
    clock_gettime(CLOCK_MONOTONIC, &now);
    double elapsed = (double)(now.tv_sec - adc_start.tv_sec) + 1e-9 * (double)(now.tv_nsec - adc_start.tv_nsec);
    if ((double)adc_rows >= elapsed * adc_rate)
        return HAL_ADC_NONE;   /* the next conversion is not done yet */
    if (adc_rows == lose_row) {
        adc_rows++;   /* its conversion is gone */
        return HAL_ADC_LOST;
    }
    for (int c = 0; c < CHANNELS; c++)
        codes[c] = host_signal(adc_rows, c);
    adc_rows++;
    return HAL_ADC_ROW;
}

size_t hal_tx_write(const uint8_t *data, size_t n)
{
    ssize_t sent = write(link_fd, data, n);
    return sent > 0 ? (size_t)sent : 0;   /* EAGAIN: the host is not reading, the pty is full */
}
