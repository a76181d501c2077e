/* The DAQ-1 instrument (see daq1.h). */
#include "daq1.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "crc32.h"

#define DEFAULT_SENSITIVITY 0.01
#define DEFAULT_RANGE 10.0
#define SENSITIVITY_LOW 1e-6
#define SENSITIVITY_HIGH 100.0
#define RANGE_LOW 0.001
#define RANGE_HIGH 50.0
#define FRAME_SECONDS 0.02
#define FLAG_OVERRUN 1u
#define FLAG_OVERLOAD 2u
#define FLAG_END 4u
#define READ_LOST_MARK INT32_MIN   /* a count the DAQ never produces (counts are clipped to +-INT32_MAX) */

static const uint8_t SYNC[4] = {0xA5, 0x5A, 0xC3, 0x3C};

/* ----- output FIFO ------------------------------------------------------------------------------ */
static size_t fifo_free(const daq1_fifo *f) { return DAQ1_FIFO_BYTES - f->count; }

/* All of `data` or nothing. */
static int fifo_put(daq1_fifo *f, const void *data, size_t n)
{
    if (n > fifo_free(f))
        return 0;
    const uint8_t *bytes = data;
    size_t tail = (f->head + f->count) % DAQ1_FIFO_BYTES;
    size_t first = n < DAQ1_FIFO_BYTES - tail ? n : DAQ1_FIFO_BYTES - tail;
    memcpy(f->data + tail, bytes, first);
    memcpy(f->data, bytes + first, n - first);
    f->count += n;
    return 1;
}

static void fifo_drain(daq1_fifo *f)
{
    while (f->count) {
        size_t run = f->count < DAQ1_FIFO_BYTES - f->head ? f->count : DAQ1_FIFO_BYTES - f->head;
        size_t sent = hal_tx_write(f->data + f->head, run);
        f->head = (f->head + sent) % DAQ1_FIFO_BYTES;
        f->count -= sent;
        if (sent < run)
            return;
    }
}

static void put_u32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

static void put_u64(uint8_t *p, uint64_t v)
{
    for (int i = 0; i < 8; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

/* ----- settings --------------------------------------------------------------------------------- */
/* Counts per ADC code and the saturation level in counts, for each scanned channel. */
static void update_scaling(daq1 *d)
{
    for (int k = 0; k < d->n_scan; k++) {
        int c = d->scan[k];
        const hal_channel *ch = &d->board->channels[c];
        double limit = floor(d->input_range[c] / d->sensitivity[c] / ch->lsb);
        d->scale[k] = ch->volts_per_code / (d->sensitivity[c] * ch->lsb);
        d->limit[k] = limit > (double)INT32_MAX ? INT32_MAX : (int32_t)limit;
    }
}

static int default_points(const daq1 *d)
{
    double points = floor(FRAME_SECONDS * d->rate + 0.5);
    points = points < 16 ? 16 : points > DAQ1_MAX_POINTS ? DAQ1_MAX_POINTS : points;
    return (int)points;
}

static void stop_acquisition(daq1 *d);

static void reset(daq1 *d)
{
    stop_acquisition(d);
    d->n_scan = d->board->n_channels;
    for (int c = 0; c < d->n_scan; c++) {
        d->scan[c] = (uint8_t)c;
        d->sensitivity[c] = DEFAULT_SENSITIVITY;
        d->input_range[c] = DEFAULT_RANGE;
    }
    d->rate = d->board->rates[0];
    d->points = default_points(d);
    update_scaling(d);
}

/* ----- acquisition ------------------------------------------------------------------------------ */
/* Counts of the scanned channels of one ADC row; whether one saturated. */
static int quantise(const daq1 *d, const int32_t *codes, int32_t *counts)
{
    int saturated = 0;
    for (int k = 0; k < d->n_scan; k++) {
        int32_t code = codes[d->scan[k]];
        double value = rint((double)code * d->scale[k]);
        int clipped = code >= d->board->channels[d->scan[k]].full_scale ||
                      code <= -d->board->channels[d->scan[k]].full_scale;
        if (value > d->limit[k] || value < -d->limit[k]) {
            value = value > 0 ? d->limit[k] : -d->limit[k];
            clipped = 1;
        }
        saturated |= clipped;
        counts[k] = (int32_t)value;
    }
    return saturated;
}

static size_t frame_bytes(int rows, int channels) { return DAQ1_FRAME_HEADER + 4u * rows * channels + 4u; }

/* Finish the frame in the assembly buffer and queue it, or lose it to a full FIFO. Data frames leave room
 * for the END frame, so that it always goes out. */
static void emit_frame(daq1 *d, int rows, unsigned flags)
{
    size_t reserve = (flags & FLAG_END) ? 0 : DAQ1_END_FRAME;
    uint8_t *f = d->frame;
    size_t size = frame_bytes(rows, d->n_scan);
    memcpy(f, SYNC, 4);
    put_u32(f + 4, d->sequence);
    put_u64(f + 8, d->acquired);
    f[16] = (uint8_t)rows;
    f[17] = (uint8_t)(rows >> 8);
    f[18] = (uint8_t)d->n_scan;
    f[19] = (uint8_t)(flags | (d->overrun_pending ? FLAG_OVERRUN : 0u));
    put_u32(f + size - 4, crc32_update(0, f, size - 4));
    /* room is always kept for the END frame */
    if (fifo_free(&d->out) >= size + reserve && fifo_put(&d->out, f, size)) {
        d->overrun_pending = 0;
    } else {
        if (!d->overrun_pending)
            scpi_queue_push(&d->errors, SCPI_FIFO_OVERRUN, "");
        d->overrun_pending = 1;
    }
    d->sequence++;
    d->acquired += (uint64_t)rows;
}

static void frame_row(daq1 *d, const int32_t *codes)
{
    int32_t counts[DAQ1_MAX_CHANNELS];
    d->overload |= quantise(d, codes, counts);
    uint8_t *p = d->frame + DAQ1_FRAME_HEADER + 4u * d->frame_rows * d->n_scan;
    for (int k = 0; k < d->n_scan; k++)
        put_u32(p + 4 * k, (uint32_t)counts[k]);
    if (++d->frame_rows == d->points) {
        emit_frame(d, d->frame_rows, d->overload ? FLAG_OVERLOAD : 0u);
        d->frame_rows = 0;
        d->overload = 0;
    }
}

static int start_acquisition(daq1 *d, scpi_status *status)
{
    if (d->streaming)
        return scpi_fail(status, SCPI_INIT_IGNORED, "acquisition already running");
    d->sequence = 0;
    d->acquired = 0;
    d->overrun_pending = d->overload = 0;
    d->frame_rows = 0;
    d->streaming = 1;
    hal_adc_start(d->rate);
    return SCPI_OK;
}

static void stop_acquisition(daq1 *d)
{
    if (!d->streaming)
        return;
    hal_adc_stop();
    if (d->frame_rows)
        emit_frame(d, d->frame_rows, d->overload ? FLAG_OVERLOAD : 0u);
    d->frame_rows = 0;
    d->overload = 0;
    /* The END frame: n = 0, sequence = data frames sent, index = samples acquired. */
    emit_frame(d, 0, FLAG_END);
    d->streaming = 0;
}

/* ----- block read ------------------------------------------------------------------------------- */
static void read_row(daq1 *d, const int32_t *codes)
{
    int32_t counts[DAQ1_MAX_CHANNELS];
    uint8_t bytes[4 * DAQ1_MAX_CHANNELS];
    quantise(d, codes, counts);
    for (int k = 0; k < d->n_scan; k++)
        put_u32(bytes + 4 * k, (uint32_t)counts[k]);
    /* in order: once a row is lost, every later one waits behind the lost rows' marks */
    if (d->read_owed || !fifo_put(&d->out, bytes, 4u * d->n_scan)) {
        d->read_owed++;
        d->read_lost++;
    }
    d->read_left--;
}

static void pay_owed_rows(daq1 *d)
{
    uint8_t bytes[4 * DAQ1_MAX_CHANNELS];
    for (int k = 0; k < d->n_scan; k++)
        put_u32(bytes + 4 * k, (uint32_t)READ_LOST_MARK);
    while (d->read_owed && fifo_put(&d->out, bytes, 4u * d->n_scan))
        d->read_owed--;
}

static int reading(const daq1 *d) { return d->read_left > 0 || d->read_owed > 0; }

/* The ADC lost conversions during a READ?: the rest of the block cannot be the next samples. */
static void read_broken(daq1 *d)
{
    d->read_owed += d->read_left;
    d->read_lost += d->read_left;
    d->read_left = 0;
}

static void finish_read(daq1 *d)
{
    hal_adc_stop();
    if (d->read_lost) {
        char detail[SCPI_DETAIL_MAX];
        snprintf(detail, sizeof detail, "READ? lost %ld samples (FIFO or ADC overrun), marked %ld",
                 d->read_lost, (long)READ_LOST_MARK);
        scpi_queue_push(&d->errors, SCPI_EXECUTION, detail);
    }
    d->read_lost = 0;
}

/* ----- commands --------------------------------------------------------------------------------- */
typedef struct {
    daq1 *d;
    scpi_unit *unit;
    long suffix;
    char *reply;        /* a query's text reply (READ? writes its block itself) */
    size_t reply_size;
    scpi_status *status;
} call;

typedef int (*handler)(call *c);

typedef struct {
    scpi_pattern pattern;
    handler write, query;
    int while_busy;
} command;

static int number_reply(call *c, double value)
{
    scpi_format_number(value, c->reply, c->reply_size);
    return SCPI_OK;
}

static int channel_index(call *c, int *index)
{
    if (c->suffix < 1 || c->suffix > c->d->board->n_channels) {
        char detail[40];
        snprintf(detail, sizeof detail, "channels are 1 to %d", c->d->board->n_channels);
        return scpi_fail(c->status, SCPI_SUFFIX_RANGE, detail);
    }
    *index = (int)c->suffix - 1;
    return SCPI_OK;
}

static int q_idn(call *c)
{
    snprintf(c->reply, c->reply_size, "contactid,DAQ-1,%s,%s", c->d->board->serial, DAQ1_VERSION);
    return scpi_expect_none(c->unit, c->status);
}

static int w_rst(call *c)
{
    if (scpi_expect_none(c->unit, c->status))
        return c->status->code;
    reset(c->d);
    return SCPI_OK;
}

static int w_cls(call *c)
{
    if (scpi_expect_none(c->unit, c->status))
        return c->status->code;
    scpi_queue_clear(&c->d->errors);
    return SCPI_OK;
}

static int q_constant(call *c, const char *text)
{
    snprintf(c->reply, c->reply_size, "%s", text);
    return scpi_expect_none(c->unit, c->status);
}

static int q_opc(call *c) { return q_constant(c, "1"); }
static int q_tst(call *c) { return q_constant(c, "0"); }
static int q_version(call *c) { return q_constant(c, "1999.0"); }

static int q_error(call *c)
{
    if (scpi_expect_none(c->unit, c->status))
        return c->status->code;
    scpi_queue_pop(&c->d->errors, c->reply, c->reply_size);
    return SCPI_OK;
}

static int q_error_count(call *c)
{
    if (scpi_expect_none(c->unit, c->status))
        return c->status->code;
    return number_reply(c, c->d->errors.count);
}

static int q_channel_count(call *c)
{
    if (scpi_expect_none(c->unit, c->status))
        return c->status->code;
    return number_reply(c, c->d->board->n_channels);
}

/* NAME?, UNIT?, LSB? of channel # */
static const hal_channel *queried_channel(call *c)
{
    int i = 0;
    if (scpi_expect_none(c->unit, c->status) || channel_index(c, &i))
        return NULL;
    return &c->d->board->channels[i];
}

static int q_name(call *c)
{
    const hal_channel *ch = queried_channel(c);
    return ch ? q_constant(c, ch->name) : c->status->code;
}

static int q_unit(call *c)
{
    const hal_channel *ch = queried_channel(c);
    return ch ? q_constant(c, ch->unit) : c->status->code;
}

static int q_lsb(call *c)
{
    const hal_channel *ch = queried_channel(c);
    return ch ? number_reply(c, ch->lsb) : c->status->code;
}

/* SENS and RANG of channel #: set or query a per-channel number in [low, high] */
static int channel_setting(call *c, double *values, double low, double high, double fallback, int query)
{
    int i = 0;
    double value;
    if (channel_index(c, &i))
        return c->status->code;
    if (query)
        return scpi_limit_query(c->unit, low, high, values[i], &value, c->status) ? c->status->code
                                                                                  : number_reply(c, value);
    if (scpi_expect_one(c->unit, c->status) ||
        scpi_parse_number(c->unit->args[0], low, high, 1, fallback, 0, &value, c->status))
        return c->status->code;
    values[i] = value;
    update_scaling(c->d);
    return SCPI_OK;
}

static int w_sens(call *c)
{
    return channel_setting(c, c->d->sensitivity, SENSITIVITY_LOW, SENSITIVITY_HIGH, DEFAULT_SENSITIVITY, 0);
}

static int q_sens(call *c)
{
    return channel_setting(c, c->d->sensitivity, SENSITIVITY_LOW, SENSITIVITY_HIGH, DEFAULT_SENSITIVITY, 1);
}

static int w_range(call *c)
{
    return channel_setting(c, c->d->input_range, RANGE_LOW, RANGE_HIGH, DEFAULT_RANGE, 0);
}

static int q_range(call *c) { return channel_setting(c, c->d->input_range, RANGE_LOW, RANGE_HIGH, DEFAULT_RANGE, 1); }

static int w_scan(call *c)
{
    uint8_t indices[DAQ1_MAX_CHANNELS];
    int n;
    if (scpi_expect_one(c->unit, c->status) ||
        scpi_parse_channel_list(c->unit->args[0], c->d->board->n_channels, indices, &n, c->status))
        return c->status->code;
    memcpy(c->d->scan, indices, (size_t)n);
    c->d->n_scan = n;
    update_scaling(c->d);
    return SCPI_OK;
}

static int q_scan(call *c)
{
    size_t used = 0;
    if (scpi_expect_none(c->unit, c->status))
        return c->status->code;
    used += (size_t)snprintf(c->reply, c->reply_size, "(@");
    for (int k = 0; k < c->d->n_scan; k++)
        used += (size_t)snprintf(c->reply + used, c->reply_size - used, k ? ",%d" : "%d", c->d->scan[k] + 1);
    snprintf(c->reply + used, c->reply_size - used, ")");
    return SCPI_OK;
}

/* "r1,r2,..." (the supported rates) */
static void format_rates(const hal_board *board, char *out, size_t size)
{
    size_t used = 0;
    out[0] = '\0';
    for (int i = 0; i < board->n_rates && used < size; i++) {
        if (i)
            out[used++] = ',';
        scpi_format_number(board->rates[i], out + used, size - used);
        used += strlen(out + used);
    }
}

static int w_rate(call *c)
{
    const hal_board *board = c->d->board;
    double rate;
    if (scpi_expect_one(c->unit, c->status) ||
        scpi_parse_number(c->unit->args[0], 0.0, HUGE_VAL, 0, 0.0, 0, &rate, c->status))
        return c->status->code;
    for (int i = 0; i < board->n_rates; i++) {
        if (fabs(rate - board->rates[i]) <= 1e-9 * board->rates[i]) {
            c->d->rate = board->rates[i];
            return SCPI_OK;
        }
    }
    char rates[SCPI_DETAIL_MAX - 40], detail[SCPI_DETAIL_MAX];
    format_rates(board, rates, sizeof rates);
    if (board->n_rates == 1)
        snprintf(detail, sizeof detail, "this DAQ samples at %s Hz only", rates);
    else
        snprintf(detail, sizeof detail, "supported rates %s Hz", rates);
    return scpi_fail(c->status, SCPI_OUT_OF_RANGE, detail);
}

static int q_rate(call *c) { return scpi_expect_none(c->unit, c->status) ? c->status->code : number_reply(c, c->d->rate); }

static int q_rate_list(call *c)
{
    if (scpi_expect_none(c->unit, c->status))
        return c->status->code;
    format_rates(c->d->board, c->reply, c->reply_size);
    return SCPI_OK;
}

static int w_points(call *c)
{
    double value;
    if (scpi_expect_one(c->unit, c->status) ||
        scpi_parse_number(c->unit->args[0], 1, DAQ1_MAX_POINTS, 1, c->d->points, 1, &value, c->status))
        return c->status->code;
    c->d->points = (int)value;
    return SCPI_OK;
}

static int q_points(call *c)
{
    double value;
    return scpi_limit_query(c->unit, 1, DAQ1_MAX_POINTS, c->d->points, &value, c->status) ? c->status->code
                                                                                          : number_reply(c, value);
}

static int q_count(call *c)
{
    return scpi_expect_none(c->unit, c->status) ? c->status->code : number_reply(c, (double)c->d->acquired);
}

static int w_init(call *c)
{
    return scpi_expect_none(c->unit, c->status) ? c->status->code : start_acquisition(c->d, c->status);
}

static int w_abort(call *c)
{
    if (scpi_expect_none(c->unit, c->status))
        return c->status->code;
    stop_acquisition(c->d);
    return SCPI_OK;
}

/* READ? n: the block header now, the samples as the ADC delivers them (daq1_poll). */
static int q_read(call *c)
{
    double n;
    char header[24];
    if (scpi_expect_one(c->unit, c->status) ||
        scpi_parse_number(c->unit->args[0], 1, (double)DAQ1_MAX_READ, 0, 0, 1, &n, c->status))
        return c->status->code;
    daq1 *d = c->d;
    char length[16];
    snprintf(length, sizeof length, "%ld", (long)n * 4L * d->n_scan);
    snprintf(header, sizeof header, "%s#%d%s", d->replies ? ";" : "", (int)strlen(length), length);
    fifo_put(&d->out, header, strlen(header));
    d->replies++;
    d->read_left = (long)n;
    d->read_owed = d->read_lost = 0;
    hal_adc_start(d->rate);
    return SCPI_OK;
}

#define NODE(w) {w, 0, 0}
#define OPT(w) {w, 1, 0}
#define SUFFIX(w) {w, 0, 1}

static const command COMMANDS[] = {
    {{{NODE("*IDN")}}, NULL, q_idn, 0},
    {{{NODE("*RST")}}, w_rst, NULL, 1},
    {{{NODE("*CLS")}}, w_cls, NULL, 1},
    {{{NODE("*OPC")}}, NULL, q_opc, 0},
    {{{NODE("*TST")}}, NULL, q_tst, 0},
    {{{NODE("SYSTem"), NODE("ERRor"), OPT("NEXT")}}, NULL, q_error, 0},
    {{{NODE("SYSTem"), NODE("ERRor"), NODE("COUNt")}}, NULL, q_error_count, 0},
    {{{NODE("SYSTem"), NODE("VERSion")}}, NULL, q_version, 0},
    {{{NODE("SYSTem"), NODE("CHANnel"), NODE("COUNt")}}, NULL, q_channel_count, 0},
    {{{NODE("SENSe"), SUFFIX("CHANnel"), NODE("NAME")}}, NULL, q_name, 0},
    {{{NODE("SENSe"), SUFFIX("CHANnel"), NODE("UNIT")}}, NULL, q_unit, 0},
    {{{NODE("SENSe"), SUFFIX("CHANnel"), NODE("LSB")}}, NULL, q_lsb, 0},
    {{{NODE("SENSe"), SUFFIX("CHANnel"), NODE("SENSitivity")}}, w_sens, q_sens, 0},
    {{{NODE("SENSe"), SUFFIX("CHANnel"), NODE("RANGe")}}, w_range, q_range, 0},
    {{{NODE("ROUTe"), NODE("SCAN")}}, w_scan, q_scan, 0},
    {{{OPT("SENSe"), NODE("SRATe")}}, w_rate, q_rate, 0},
    {{{OPT("SENSe"), NODE("SRATe"), NODE("LIST")}}, NULL, q_rate_list, 0},
    {{{NODE("STReam"), NODE("POINts")}}, w_points, q_points, 0},
    {{{NODE("STReam"), NODE("COUNt")}}, NULL, q_count, 0},
    {{{NODE("INITiate"), OPT("IMMediate")}}, w_init, NULL, 1},
    {{{NODE("ABORt")}}, w_abort, NULL, 1},
    {{{NODE("READ")}}, NULL, q_read, 0},
};

static const command *lookup(const char *header, long *suffix)
{
    for (size_t i = 0; i < sizeof COMMANDS / sizeof COMMANDS[0]; i++)
        if (scpi_match(&COMMANDS[i].pattern, header, suffix))
            return &COMMANDS[i];
    return NULL;
}

/* Execute one unit; its text reply (if any) goes to the FIFO after a ';' unless it is the first. */
static int execute_unit(daq1 *d, char *text, scpi_status *status)
{
    scpi_unit unit;
    long suffix;
    char reply[160];
    if (scpi_parse_unit(text, &unit, status))
        return status->code;
    const command *cmd = lookup(unit.header, &suffix);
    if (!cmd) {
        char shown[41];
        snprintf(shown, sizeof shown, "%s", unit.header);
        return scpi_fail(status, SCPI_UNDEFINED_HEADER, shown);
    }
    handler run = unit.query ? cmd->query : cmd->write;
    if (!run) {
        char detail[SCPI_DETAIL_MAX];
        snprintf(detail, sizeof detail, "%.40s%s is %s", unit.header, unit.query ? "?" : "",
                 unit.query ? "not a query" : "query only");
        return scpi_fail(status, SCPI_UNDEFINED_HEADER, detail);
    }
    if (d->busy && !cmd->while_busy)
        return scpi_fail(status, SCPI_SETTINGS_CONFLICT, "acquisition running; send ABORt first");
    if (unit.nargs > SCPI_MAX_ARGS)
        return scpi_fail(status, SCPI_PARAM_NOT_ALLOWED, "");
    call c = {d, &unit, suffix, reply, sizeof reply, status};
    reply[0] = '\0';
    if (run(&c))
        return status->code;
    if (unit.query && run != q_read) {
        if ((d->replies && !fifo_put(&d->out, ";", 1)) || !fifo_put(&d->out, reply, strlen(reply)))
            return scpi_fail(status, SCPI_DEVICE, "reply longer than the output FIFO");
        d->replies++;
    }
    return SCPI_OK;
}

/* Run units of the current message until it ends or a READ? suspends it. */
static void run_message(daq1 *d)
{
    char *unit;
    while (!reading(d) && (unit = scpi_next_piece(&d->cursor, ';')) != NULL) {
        scpi_status status = {0, ""};
        unit = scpi_strip(unit);
        if (*unit && execute_unit(d, unit, &status))
            scpi_queue_push(&d->errors, status.code, status.detail);
    }
    if (!reading(d) && !d->cursor) {
        if (d->replies)
            fifo_put(&d->out, "\n", 1);
        d->executing = 0;
    }
}

static int is_ascii(const char *text, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if ((unsigned char)text[i] > 127)
            return 0;
    return 1;
}

/* Start the waiting message: idle, only once every earlier reply has gone out (the FIFO is then free for
 * the longest reply); streaming, at once (only commands without replies run then). */
static void start_message(daq1 *d)
{
    if (!d->line_ready || d->executing || (!d->streaming && d->out.count))
        return;
    d->line_ready = 0;
    if (!is_ascii(d->line, d->line_len)) {
        scpi_queue_push(&d->errors, SCPI_SYNTAX, "non-ASCII byte");
        d->line_len = 0;
        return;
    }
    if (memchr(d->line, '\0', d->line_len)) {   /* C text ends there: the message is not executed */
        scpi_queue_push(&d->errors, SCPI_SYNTAX, "NUL byte");
        d->line_len = 0;
        return;
    }
    memcpy(d->message, d->line, d->line_len);
    d->message[d->line_len] = '\0';
    d->line_len = 0;
    d->cursor = d->message;
    d->replies = 0;
    d->busy = d->streaming;
    d->executing = 1;
    run_message(d);
}

/* ----- public ----------------------------------------------------------------------------------- */
void daq1_init(daq1 *d, const hal_board *board)
{
    memset(d, 0, sizeof *d);
    d->board = board;
    reset(d);
}

int daq1_accepts_input(const daq1 *d) { return !d->line_ready; }

int daq1_acquiring(const daq1 *d) { return d->streaming || reading(d); }

size_t daq1_output_pending(const daq1 *d) { return d->out.count; }

size_t daq1_receive(daq1 *d, const uint8_t *data, size_t n)
{
    size_t i;
    for (i = 0; i < n && !d->line_ready; i++) {
        uint8_t byte = data[i];
        if (byte == '\n') {
            if (d->overlong) {
                d->overlong = 0;
            } else {
                if (d->line_len && d->line[d->line_len - 1] == '\r')
                    d->line_len--;
                d->line_ready = 1;
            }
        } else if (d->overlong) {
            continue;
        } else if (d->line_len == DAQ1_MAX_LINE) {
            /* not executed, in whole or in part: -363 once, the rest up to its LF dropped */
            scpi_queue_push(&d->errors, SCPI_INPUT_OVERRUN, "");
            d->overlong = 1;
            d->line_len = 0;
        } else {
            d->line[d->line_len++] = (char)byte;
        }
    }
    return i;
}

/* The stream cannot go on with samples missing that no frame accounts for: it ends, saying why. */
static void stream_broken(daq1 *d)
{
    scpi_queue_push(&d->errors, SCPI_DEVICE, "ADC conversions lost; acquisition stopped");
    stop_acquisition(d);
}

void daq1_poll(daq1 *d)
{
    int32_t codes[DAQ1_MAX_CHANNELS];
    int got;
    start_message(d);
    if (d->streaming) {
        while (d->streaming && (got = hal_adc_read(codes)) != HAL_ADC_NONE)
            got == HAL_ADC_ROW ? frame_row(d, codes) : stream_broken(d);
    } else if (reading(d)) {
        pay_owed_rows(d);
        while (d->read_left > 0 && (got = hal_adc_read(codes)) != HAL_ADC_NONE)
            got == HAL_ADC_ROW ? read_row(d, codes) : read_broken(d);
        pay_owed_rows(d);
        if (!reading(d))
            finish_read(d);
    }
    if (d->executing)
        run_message(d);
    fifo_drain(&d->out);
}
