/* The host board (host_hal.c): configuration from the command line. */
#ifndef HOST_HAL_H
#define HOST_HAL_H
#include <stdint.h>
#include "../core/hal.h"
typedef struct {
    const char *serial;
    const double *rates;
    int n_rates;
    long lose_row;     /* the ADC loses the conversion of this row after every start (-1: never) */
} host_options;

void host_hal_setup(const host_options *options, int fd);
/* ADC code of row k of channel c: the test signal. */
int32_t host_signal(int64_t k, int channel);
#endif
