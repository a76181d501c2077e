/* The DAQ-1 instrument (docs/protocol.md section 6): program messages in, replies and frames out.
 * Portable C99, no allocation, no board dependency: the board is reached through hal.h. */
#ifndef DAQ1_H
#define DAQ1_H
#include <stddef.h>
#include <stdint.h>

#include "hal.h"
#include "scpi.h"

#define DAQ1_VERSION "1.0"
#define DAQ1_MAX_LINE 4096            /* bytes of a program message before its LF */
#define DAQ1_MAX_CHANNELS 4          /* a board has at most this many (ADS131M04: 4) */
#define DAQ1_MAX_POINTS 4096          /* STReam:POINts limit (u16 field) */
#define DAQ1_MAX_READ (1L << 20)      /* READ? limit, samples per channel */
#ifndef DAQ1_FIFO_BYTES
#define DAQ1_FIFO_BYTES (96u * 1024u) /* output FIFO; RP2040: 264 KiB of RAM */
#endif
#define DAQ1_FRAME_HEADER 20
#define DAQ1_END_FRAME 24

typedef struct {
    uint8_t data[DAQ1_FIFO_BYTES];
    size_t head, count;
} daq1_fifo;

typedef struct {
    const hal_board *board;
    scpi_queue errors;
    /* settings */
    uint8_t scan[DAQ1_MAX_CHANNELS];
    int n_scan;
    double sensitivity[DAQ1_MAX_CHANNELS], input_range[DAQ1_MAX_CHANNELS];
    double rate;
    int points;
    /* input: one program message at a time */
    char line[DAQ1_MAX_LINE + 1];
    size_t line_len;
    int line_ready, overlong;
    /* the message being executed (suspended while a READ? runs) */
    char message[DAQ1_MAX_LINE + 1];
    char *cursor;
    int executing, replies;
    int busy;             /* streaming when the message started: its units run as while streaming */
    /* acquisition */
    int streaming;
    uint32_t sequence;
    uint64_t acquired;
    int overrun_pending, overload;
    int frame_rows;
    uint8_t frame[DAQ1_FRAME_HEADER + 4 * DAQ1_MAX_POINTS * DAQ1_MAX_CHANNELS + 4];
    /* block read */
    long read_left, read_owed, read_lost;
    /* scaling of the scanned channels: counts = rint(code * scale), clipped at +-limit */
    double scale[DAQ1_MAX_CHANNELS];
    int32_t limit[DAQ1_MAX_CHANNELS];
    daq1_fifo out;
} daq1;

void daq1_init(daq1 *d, const hal_board *board);
/* Whether the core takes more input bytes now (it holds at most one program message). */
int daq1_accepts_input(const daq1 *d);
/* Take input bytes; the number consumed (stops after a complete message). */
size_t daq1_receive(daq1 *d, const uint8_t *data, size_t n);
/* Whether the ADC runs for a stream or a READ? (then the board polls at the ADC's pace). */
int daq1_acquiring(const daq1 *d);
/* Bytes waiting for the link. */
size_t daq1_output_pending(const daq1 *d);
/* Execute what can be executed, acquire the ADC rows that are ready, send what the link takes. */
void daq1_poll(daq1 *d);

#endif
