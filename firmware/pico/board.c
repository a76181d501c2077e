/* Raspberry Pi Pico + ADS131M04: the DAQ-1 board glue (hal.h). Wiring in docs/firmware.md.
 *
 * The ADS131M04 converts all the time (CLKIN 8.192 MHz from an oscillator, high-resolution mode); each
 * falling edge of DRDY raises an interrupt that reads one SPI frame (status, 4 channels, CRC: 6 words of
 * 24 bits) and, while the core acquires, queues the row in a ring the main loop empties. A full ring stops
 * queueing until the main loop has taken every row, then reports HAL_ADC_LOST: rows stay in order and a
 * loss is never hidden. */
#include <string.h>

#include "daq1.h"
#include "hardware/gpio.h"
#include "hardware/spi.h"
#include "pico/stdlib.h"
#include "pico/unique_id.h"
#include "tusb.h"

#define ADC_SPI spi0
#define PIN_MISO 16
#define PIN_CS 17
#define PIN_SCK 18
#define PIN_MOSI 19
#define PIN_DRDY 20
#define PIN_SYNC_RESET 21
#define SPI_HZ 20000000       /* ADS131M04: SCLK up to 25 MHz */
#define CHANNELS 4
#define WORD 3                /* bytes per SPI word (24-bit mode, the reset default) */
#define FRAME_WORDS 6         /* status, 4 channels, CRC */
#define RING_ROWS 1024        /* 32 ms at 32 kHz */
#define REG_CLOCK 0x03
#define CLOCK_ALL_CHANNELS 0x0F00u
#define CLOCK_HIGH_RESOLUTION 0x0002u

/* Input volts per code at the sensor: +-1.2 V full scale at gain 1, behind a 5:1 divider (front end). */
#define VOLTS_PER_CODE (5.0 * 1.2 / 8388608.0)
#define FULL_SCALE 0x7FFFFF

typedef char channels_fit_the_core[CHANNELS <= DAQ1_MAX_CHANNELS ? 1 : -1];

static const hal_channel CHANNEL_TABLE[CHANNELS] = {
    {"force", "N", 1e-5, VOLTS_PER_CODE, FULL_SCALE},
    {"acc:x1", "m/s^2", 1e-5, VOLTS_PER_CODE, FULL_SCALE},
    {"acc:x2", "m/s^2", 1e-5, VOLTS_PER_CODE, FULL_SCALE},
    {"acc:x3", "m/s^2", 1e-5, VOLTS_PER_CODE, FULL_SCALE},
};

/* Data rate = 8.192 MHz / 2 / OSR; OSR code 5 (4096) .. 0 (128). */
static const double RATES[] = {1000.0, 2000.0, 4000.0, 8000.0, 16000.0, 32000.0};
#define N_RATES ((int)(sizeof RATES / sizeof RATES[0]))

static char serial_text[2 * PICO_UNIQUE_BOARD_ID_SIZE_BYTES + 1];
static hal_board board = {serial_text, CHANNEL_TABLE, CHANNELS, RATES, N_RATES};

static int32_t ring[RING_ROWS][CHANNELS];
static volatile uint32_t ring_head, ring_tail;   /* head: written by the interrupt; tail: by the main loop */
static volatile bool acquiring, lost;

static int32_t word_at(const uint8_t *frame, int index)
{
    const uint8_t *w = frame + WORD * index;
    return (int32_t)(((uint32_t)w[0] << 24) | ((uint32_t)w[1] << 16) | ((uint32_t)w[2] << 8)) >> 8;
}

/* One SPI frame: `command` (16 bits) and `data` (16 bits) out, the conversion results in. */
static void spi_frame(uint16_t command, uint16_t data, uint8_t *in)
{
    uint8_t out[WORD * FRAME_WORDS] = {0};
    out[0] = (uint8_t)(command >> 8);
    out[1] = (uint8_t)command;
    out[3] = (uint8_t)(data >> 8);
    out[4] = (uint8_t)data;
    gpio_put(PIN_CS, 0);
    spi_write_read_blocking(ADC_SPI, out, in, sizeof out);
    gpio_put(PIN_CS, 1);
}

static void drdy_interrupt(uint gpio, uint32_t events)
{
    uint8_t in[WORD * FRAME_WORDS];
    (void)gpio;
    (void)events;
    spi_frame(0x0000, 0x0000, in);   /* NULL command: read the conversion */
    if (!acquiring)
        return;
    uint32_t next = (ring_head + 1) % RING_ROWS;
    if (lost || next == ring_tail) {
        lost = true;
        return;
    }
    for (int c = 0; c < CHANNELS; c++)
        ring[ring_head][c] = word_at(in, 1 + c);
    ring_head = next;
}

const hal_board *hal_board_info(void) { return &board; }

void hal_adc_start(double rate)
{
    uint8_t in[WORD * FRAME_WORDS];
    int code = 0;
    for (int i = 0; i < N_RATES; i++)
        if (RATES[i] == rate)
            code = 5 - i;
    gpio_set_irq_enabled(PIN_DRDY, GPIO_IRQ_EDGE_FALL, false);
    acquiring = false;
    spi_frame(0x6000 | (REG_CLOCK << 7), CLOCK_ALL_CHANNELS | (uint16_t)(code << 2) | CLOCK_HIGH_RESOLUTION, in);
    /* SYNC: a low pulse shorter than 2048 CLKIN periods (250 us) restarts the filters; the next DRDY
     * brings settled data, sample 0 */
    gpio_put(PIN_SYNC_RESET, 0);
    busy_wait_us(10);
    gpio_put(PIN_SYNC_RESET, 1);
    ring_head = ring_tail = 0;
    lost = false;
    acquiring = true;
    gpio_acknowledge_irq(PIN_DRDY, GPIO_IRQ_EDGE_FALL);   /* an edge from before the SYNC is not sample 0 */
    gpio_set_irq_enabled(PIN_DRDY, GPIO_IRQ_EDGE_FALL, true);
}

void hal_adc_stop(void) { acquiring = false; }

int hal_adc_read(int32_t *codes)
{
    uint32_t tail = ring_tail;
    if (tail == ring_head) {
        if (!lost)
            return HAL_ADC_NONE;
        lost = false;   /* every row before the loss has been taken */
        return HAL_ADC_LOST;
    }
    memcpy(codes, ring[tail], sizeof ring[tail]);
    ring_tail = (tail + 1) % RING_ROWS;
    return HAL_ADC_ROW;
}

size_t hal_tx_write(const uint8_t *data, size_t n)
{
    uint32_t room = tud_cdc_write_available();
    if (n > room)
        n = room;
    if (n) {
        tud_cdc_write(data, (uint32_t)n);
        tud_cdc_write_flush();
    }
    return n;
}

void daq1_board_init(void)
{
    pico_get_unique_board_id_string(serial_text, sizeof serial_text);
    spi_init(ADC_SPI, SPI_HZ);
    spi_set_format(ADC_SPI, 8, SPI_CPOL_0, SPI_CPHA_1, SPI_MSB_FIRST);   /* ADS131M04: SPI mode 1 */
    gpio_set_function(PIN_MISO, GPIO_FUNC_SPI);
    gpio_set_function(PIN_SCK, GPIO_FUNC_SPI);
    gpio_set_function(PIN_MOSI, GPIO_FUNC_SPI);
    gpio_init(PIN_CS);
    gpio_set_dir(PIN_CS, GPIO_OUT);
    gpio_put(PIN_CS, 1);
    gpio_init(PIN_SYNC_RESET);
    gpio_set_dir(PIN_SYNC_RESET, GPIO_OUT);
    gpio_put(PIN_SYNC_RESET, 0);   /* reset: low for more than 2048 CLKIN periods */
    sleep_ms(1);
    gpio_put(PIN_SYNC_RESET, 1);
    sleep_ms(1);
    gpio_init(PIN_DRDY);
    gpio_set_dir(PIN_DRDY, GPIO_IN);
    gpio_set_irq_enabled_with_callback(PIN_DRDY, GPIO_IRQ_EDGE_FALL, true, drdy_interrupt);
}
