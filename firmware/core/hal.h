/* What the DAQ-1 protocol core needs from a board: its channels, an ADC, a byte link out.
 * The board glue implements these; bytes in are handed to daq1_receive(). */
#ifndef HAL_H
#define HAL_H
#include <stddef.h>
#include <stdint.h>

typedef struct {
    const char *name;        /* "force", "acc:x1" */
    const char *unit;        /* "N", "m/s^2" */
    double lsb;              /* physical value of one count of the stream (fixed) */
    double volts_per_code;   /* ADC input volts per ADC code */
    int32_t full_scale;      /* largest ADC code magnitude: a code beyond it is clipped by the ADC */
} hal_channel;

typedef struct {
    const char *serial;      /* *IDN? serial number field */
    const hal_channel *channels;
    int n_channels;
    const double *rates;     /* supported sample rates, Hz; the first is the *RST rate */
    int n_rates;
} hal_board;

const hal_board *hal_board_info(void);
/* Start converting at `rate` (one of the board's rates); the next row read is sample 0. */
void hal_adc_start(double rate);
void hal_adc_stop(void);
/* One row of ADC codes (all channels, in board order): HAL_ADC_ROW; HAL_ADC_NONE when none is ready;
 * HAL_ADC_LOST when conversions were lost since the last row (the board could not keep up). */
enum { HAL_ADC_LOST = -1, HAL_ADC_NONE = 0, HAL_ADC_ROW = 1 };
int hal_adc_read(int32_t *codes);
/* Send what the link takes now (never blocks); the number of bytes accepted. */
size_t hal_tx_write(const uint8_t *data, size_t n);

#endif
