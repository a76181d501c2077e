/* SCPI building blocks for the DAQ-1 firmware: headers, parameters, numbers, error queue.
 * Portable C99, no allocation. docs/protocol.md sections 2 and 3 are the contract. */
#ifndef SCPI_H
#define SCPI_H

#include <stddef.h>
#include <stdint.h>

#define SCPI_QUEUE_LENGTH 20
#define SCPI_DETAIL_MAX 96   /* characters of detail after "<message>;" */
#define SCPI_MAX_ARGS 8
#define SCPI_MAX_NODES 4

/* Error codes (docs/protocol.md section 3). */
enum {
    SCPI_OK = 0, SCPI_SYNTAX = -102, SCPI_DATA_TYPE = -104, SCPI_PARAM_NOT_ALLOWED = -108,
    SCPI_MISSING_PARAM = -109, SCPI_UNDEFINED_HEADER = -113, SCPI_SUFFIX_RANGE = -114,
    SCPI_INVALID_SUFFIX = -131, SCPI_EXECUTION = -200, SCPI_INIT_IGNORED = -213, SCPI_SETTINGS_CONFLICT = -221,
    SCPI_OUT_OF_RANGE = -222, SCPI_ILLEGAL_VALUE = -224, SCPI_DEVICE = -300, SCPI_QUEUE_OVERFLOW = -350,
    SCPI_INPUT_OVERRUN = -363, SCPI_FIFO_OVERRUN = 301
};

typedef struct {
    int16_t code;
    char detail[SCPI_DETAIL_MAX];
} scpi_entry;

/* Oldest first; when full the newest entry becomes -350. */
typedef struct {
    scpi_entry entries[SCPI_QUEUE_LENGTH];
    uint8_t head, count;
} scpi_queue;

void scpi_queue_clear(scpi_queue *q);
void scpi_queue_push(scpi_queue *q, int code, const char *detail);
/* Remove the oldest entry and write `<code>,"<message>[;detail]"` (0,"No error" when empty). */
void scpi_queue_pop(scpi_queue *q, char *out, size_t size);

/* One node of a header pattern: `word` in SCPI notation (capitals = short form), optional, numeric suffix. */
typedef struct {
    const char *word;
    uint8_t optional;
    uint8_t suffix;
} scpi_node;

/* A header pattern: up to SCPI_MAX_NODES nodes, unused ones have word NULL. */
typedef struct {
    scpi_node nodes[SCPI_MAX_NODES];
} scpi_pattern;

/* A failed step: its code and the detail text (empty for none). */
typedef struct {
    int code;
    char detail[SCPI_DETAIL_MAX];
} scpi_status;

int scpi_fail(scpi_status *status, int code, const char *detail);

/* A unit of a program message split into header and parameters (pointers into the unit's text). */
typedef struct {
    char *header;       /* without a trailing '?' */
    int query;
    char *args[SCPI_MAX_ARGS];
    int nargs;          /* SCPI_MAX_ARGS + 1 when there were more */
} scpi_unit;

/* Next `separator`-separated piece of `text` outside quotes and parentheses; NULL at the end.
 * `*cursor` starts at `text`; the piece is terminated in place. */
char *scpi_next_piece(char **cursor, char separator);
/* Strip leading and trailing blanks in place. */
char *scpi_strip(char *text);
/* Split a unit in place; a malformed header is -102. */
int scpi_parse_unit(char *unit, scpi_unit *out, scpi_status *status);
/* Whether `header` spells `pattern`; the numeric suffix (1 when omitted, -1 when too long) in *suffix. */
int scpi_match(const scpi_pattern *pattern, const char *header, long *suffix);
/* Whether `text` spells the mnemonic `word` (short or long form, case-insensitive). */
int scpi_keyword(const char *text, const char *word);

int scpi_expect_none(const scpi_unit *unit, scpi_status *status);
int scpi_expect_one(const scpi_unit *unit, scpi_status *status);
/* A number in [low, high]; MINimum, MAXimum and (when has_default) DEFault accepted. */
int scpi_parse_number(const char *text, double low, double high, int has_default, double fallback,
                      int integer, double *value, scpi_status *status);
/* The value of `X?`, `X? MIN` or `X? MAX`. */
int scpi_limit_query(const scpi_unit *unit, double low, double high, double current, double *value,
                     scpi_status *status);
/* `(@1,3:4)` to zero-based indices; each channel in 1..count, no repeats. */
int scpi_parse_channel_list(const char *text, int count, uint8_t *indices, int *n, scpi_status *status);
/* Shortest text that reads back as the same double; whole numbers without a point. */
void scpi_format_number(double value, char *out, size_t size);

#endif
