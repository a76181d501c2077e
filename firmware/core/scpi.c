/* SCPI building blocks (see scpi.h). */
#include "scpi.h"

#include <ctype.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const struct { int16_t code; const char *text; } MESSAGES[] = {
    {0, "No error"}, {-102, "Syntax error"}, {-104, "Data type error"}, {-108, "Parameter not allowed"},
    {-109, "Missing parameter"}, {-113, "Undefined header"}, {-114, "Header suffix out of range"},
    {-131, "Invalid suffix"}, {-200, "Execution error"}, {-213, "Init ignored"}, {-221, "Settings conflict"},
    {-222, "Data out of range"}, {-224, "Illegal parameter value"}, {-300, "Device-specific error"},
    {-350, "Queue overflow"}, {-363, "Input buffer overrun"}, {301, "Acquisition FIFO overrun; frames lost"},
};

static const char *message_text(int code)
{
    for (size_t i = 0; i < sizeof MESSAGES / sizeof MESSAGES[0]; i++)
        if (MESSAGES[i].code == code)
            return MESSAGES[i].text;
    return "Device-specific error";
}

static void copy_text(char *out, size_t size, const char *text)
{
    size_t n = strlen(text);
    if (n >= size)
        n = size - 1;
    memcpy(out, text, n);
    out[n] = '\0';
}

void scpi_queue_clear(scpi_queue *q) { q->head = q->count = 0; }

void scpi_queue_push(scpi_queue *q, int code, const char *detail)
{
    scpi_entry *entry;
    if (q->count >= SCPI_QUEUE_LENGTH) {
        entry = &q->entries[(q->head + SCPI_QUEUE_LENGTH - 1) % SCPI_QUEUE_LENGTH];
        code = SCPI_QUEUE_OVERFLOW;
        detail = "";
    } else {
        entry = &q->entries[(q->head + q->count) % SCPI_QUEUE_LENGTH];
        q->count++;
    }
    entry->code = (int16_t)code;
    copy_text(entry->detail, sizeof entry->detail, detail ? detail : "");
}

void scpi_queue_pop(scpi_queue *q, char *out, size_t size)
{
    if (!q->count) {
        snprintf(out, size, "0,\"No error\"");
        return;
    }
    const scpi_entry *e = &q->entries[q->head];
    snprintf(out, size, "%d,\"%s%s%s\"", e->code, message_text(e->code), e->detail[0] ? ";" : "", e->detail);
    q->head = (uint8_t)((q->head + 1) % SCPI_QUEUE_LENGTH);
    q->count--;
}

int scpi_fail(scpi_status *status, int code, const char *detail)
{
    status->code = code;
    copy_text(status->detail, sizeof status->detail, detail ? detail : "");
    return code;
}

char *scpi_next_piece(char **cursor, char separator)
{
    char *start = *cursor, *p;
    int depth = 0, quoted = 0;
    if (!start)
        return NULL;
    for (p = start; *p; p++) {
        if (*p == '"')
            quoted = !quoted;
        else if (!quoted && *p == '(')
            depth++;
        else if (!quoted && *p == ')')
            depth = depth > 0 ? depth - 1 : 0;
        else if (!quoted && !depth && *p == separator)
            break;
    }
    if (*p) {
        *p = '\0';
        *cursor = p + 1;
    } else {
        *cursor = NULL;
    }
    return start;
}

char *scpi_strip(char *text)
{
    while (*text == ' ' || *text == '\t')
        text++;
    size_t n = strlen(text);
    while (n && (text[n - 1] == ' ' || text[n - 1] == '\t'))
        text[--n] = '\0';
    return text;
}

/* `:?[*A-Za-z][A-Za-z0-9:]*\??` */
static int header_well_formed(const char *h)
{
    if (*h == ':')
        h++;
    if (!(*h == '*' || isalpha((unsigned char)*h)))
        return 0;
    for (h++; *h && *h != '?'; h++)
        if (!(isalnum((unsigned char)*h) || *h == ':'))
            return 0;
    return *h == '\0' || (h[0] == '?' && h[1] == '\0');
}

int scpi_parse_unit(char *unit, scpi_unit *out, scpi_status *status)
{
    char *space = strchr(unit, ' ');
    char *rest = NULL;
    if (space) {
        *space = '\0';
        rest = space + 1;
    }
    if (!*unit || !header_well_formed(unit)) {
        char shown[41];
        if (space)
            *space = ' ';
        copy_text(shown, sizeof shown, unit);
        return scpi_fail(status, SCPI_SYNTAX, shown);
    }
    size_t n = strlen(unit);
    out->query = unit[n - 1] == '?';
    if (out->query)
        unit[n - 1] = '\0';
    out->header = unit;
    out->nargs = 0;
    if (rest && *scpi_strip(rest)) {
        char *cursor = scpi_strip(rest), *arg;
        while ((arg = scpi_next_piece(&cursor, ',')) != NULL) {
            if (out->nargs < SCPI_MAX_ARGS)
                out->args[out->nargs] = scpi_strip(arg);
            if (out->nargs <= SCPI_MAX_ARGS)
                out->nargs++;
        }
    }
    return SCPI_OK;
}

static int spells(const char *text, size_t len, const char *word, int short_form)
{
    size_t i = 0;
    for (const char *w = word; *w; w++) {
        if (short_form && !(isupper((unsigned char)*w) || isdigit((unsigned char)*w) || *w == '*'))
            continue;
        if (i >= len || toupper((unsigned char)text[i]) != toupper((unsigned char)*w))
            return 0;
        i++;
    }
    return i == len;
}

static int node_matches(const scpi_node *node, const char *text, size_t len, long *suffix)
{
    size_t word_len = len;
    if (node->suffix)
        while (word_len && isdigit((unsigned char)text[word_len - 1]))
            word_len--;
    if (!spells(text, word_len, node->word, 1) && !spells(text, word_len, node->word, 0))
        return 0;
    if (node->suffix) {
        size_t digits = len - word_len;
        *suffix = digits == 0 ? 1 : digits > 9 ? -1 : strtol(text + word_len, NULL, 10);
    }
    return 1;
}

static int match_from(const scpi_node *nodes, int n_nodes, const char *header, long *suffix)
{
    if (n_nodes == 0 || !nodes->word)
        return *header == '\0';
    if (nodes->optional && match_from(nodes + 1, n_nodes - 1, header, suffix))
        return 1;
    if (!*header)
        return 0;
    const char *end = strchr(header, ':');
    size_t len = end ? (size_t)(end - header) : strlen(header);
    if (!node_matches(nodes, header, len, suffix))
        return 0;
    if (end && !end[1])
        return 0;   /* a trailing ':' */
    return match_from(nodes + 1, n_nodes - 1, end ? end + 1 : header + len, suffix);
}

int scpi_match(const scpi_pattern *pattern, const char *header, long *suffix)
{
    *suffix = 1;
    if (*header == ':')
        header++;
    return match_from(pattern->nodes, SCPI_MAX_NODES, header, suffix);
}

int scpi_keyword(const char *text, const char *word)
{
    size_t len = strlen(text);
    return spells(text, len, word, 1) || spells(text, len, word, 0);
}

int scpi_expect_none(const scpi_unit *unit, scpi_status *status)
{
    return unit->nargs ? scpi_fail(status, SCPI_PARAM_NOT_ALLOWED, "") : SCPI_OK;
}

int scpi_expect_one(const scpi_unit *unit, scpi_status *status)
{
    if (!unit->nargs || !unit->args[0][0])
        return scpi_fail(status, SCPI_MISSING_PARAM, "");
    return unit->nargs > 1 ? scpi_fail(status, SCPI_PARAM_NOT_ALLOWED, "") : SCPI_OK;
}

/* Length of the leading `[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?` of text, 0 if none. */
static size_t number_length(const char *t)
{
    size_t i = 0, digits = 0;
    if (t[i] == '+' || t[i] == '-')
        i++;
    while (isdigit((unsigned char)t[i])) { i++; digits++; }
    if (t[i] == '.') {
        i++;
        while (isdigit((unsigned char)t[i])) { i++; digits++; }
    }
    if (!digits)
        return 0;
    if (t[i] == 'e' || t[i] == 'E') {
        size_t j = i + 1;
        if (t[j] == '+' || t[j] == '-')
            j++;
        if (isdigit((unsigned char)t[j])) {
            while (isdigit((unsigned char)t[j]))
                j++;
            i = j;
        }
    }
    return i;
}

static int is_unit_suffix(const char *t)
{
    while (*t == ' ' || *t == '\t')
        t++;
    if (!*t)
        return 0;
    for (; *t; t++)
        if (!isalpha((unsigned char)*t))
            return 0;
    return 1;
}

static int range_error(scpi_status *status, double low, double high)
{
    char lo[32], hi[32], detail[80];
    scpi_format_number(low, lo, sizeof lo);
    scpi_format_number(high, hi, sizeof hi);
    snprintf(detail, sizeof detail, "valid range %s to %s", lo, hi);
    return scpi_fail(status, SCPI_OUT_OF_RANGE, detail);
}

int scpi_parse_number(const char *text, double low, double high, int has_default, double fallback,
                      int integer, double *value, scpi_status *status)
{
    if (scpi_keyword(text, "MINimum")) { *value = low; return SCPI_OK; }
    if (scpi_keyword(text, "MAXimum")) { *value = high; return SCPI_OK; }
    if (has_default && scpi_keyword(text, "DEFault")) { *value = fallback; return SCPI_OK; }
    size_t n = number_length(text);
    if (n && text[n] == '\0') {
        *value = strtod(text, NULL);
    } else if (n && is_unit_suffix(text + n)) {
        return scpi_fail(status, SCPI_INVALID_SUFFIX, "values are in SI base units without suffix");
    } else {
        char detail[48];
        snprintf(detail, sizeof detail, "expected a number, got '%.20s'", text);
        return scpi_fail(status, SCPI_DATA_TYPE, detail);
    }
    if (integer && *value != floor(*value))
        return scpi_fail(status, SCPI_DATA_TYPE, "expected an integer");
    if (!(low <= *value && *value <= high))
        return range_error(status, low, high);
    return SCPI_OK;
}

int scpi_limit_query(const scpi_unit *unit, double low, double high, double current, double *value,
                     scpi_status *status)
{
    if (!unit->nargs) {
        *value = current;
        return SCPI_OK;
    }
    if (scpi_expect_one(unit, status))
        return status->code;
    if (scpi_keyword(unit->args[0], "MINimum"))
        *value = low;
    else if (scpi_keyword(unit->args[0], "MAXimum"))
        *value = high;
    else
        return scpi_fail(status, SCPI_ILLEGAL_VALUE, "expected MIN|MAX");
    return SCPI_OK;
}

static int all_digits(const char *t, size_t n)
{
    if (!n)
        return 0;
    for (size_t i = 0; i < n; i++)
        if (!isdigit((unsigned char)t[i]))
            return 0;
    return 1;
}

/* One item `a` or `a:b` of a channel list (blanks around the numbers allowed), stripped in place. */
static int channel_item(char *item, long *first, long *last)
{
    char *bounds[2];
    int n = 0;
    char *cursor = item, *piece;
    while ((piece = scpi_next_piece(&cursor, ':')) != NULL) {
        if (n == 2)
            return 0;
        bounds[n++] = scpi_strip(piece);
    }
    for (int i = 0; i < n; i++)
        if (!all_digits(bounds[i], strlen(bounds[i])))
            return 0;
    /* more than 6 digits is out of any channel range */
    *first = strlen(bounds[0]) > 6 ? 1000000 : strtol(bounds[0], NULL, 10);
    *last = strlen(bounds[n - 1]) > 6 ? 1000000 : strtol(bounds[n - 1], NULL, 10);
    return 1;
}

int scpi_parse_channel_list(const char *text, int count, uint8_t *indices, int *n, scpi_status *status)
{
    const char *p = text, *end;
    while (*p == ' ' || *p == '\t')
        p++;
    end = p + strlen(p);
    while (end > p && (end[-1] == ' ' || end[-1] == '\t'))
        end--;
    if (*p != '(' || end - p < 2 || end[-1] != ')')
        return scpi_fail(status, SCPI_DATA_TYPE, "expected a channel list such as (@1,2:4)");
    p++;
    end--;
    while (*p == ' ' || *p == '\t')
        p++;
    if (*p != '@')
        return scpi_fail(status, SCPI_DATA_TYPE, "expected a channel list such as (@1,2:4)");
    p++;
    for (const char *q = p; q < end; q++)
        if (!(isdigit((unsigned char)*q) || *q == ':' || *q == ',' || *q == ' ' || *q == '\t'))
            return scpi_fail(status, SCPI_DATA_TYPE, "expected a channel list such as (@1,2:4)");
    if (p == end)
        return scpi_fail(status, SCPI_DATA_TYPE, "expected a channel list such as (@1,2:4)");
    uint32_t seen = 0;
    int total = 0, repeated = 0;
    while (p <= end) {
        const char *comma = memchr(p, ',', (size_t)(end - p));
        const char *stop = comma ? comma : end;
        char item[24];
        long first, last;
        size_t len = (size_t)(stop - p) < sizeof item - 1 ? (size_t)(stop - p) : sizeof item - 1;
        memcpy(item, p, len);
        item[len] = '\0';
        if (!channel_item(item, &first, &last)) {   /* (a longer item is judged by its first 23 bytes) */
            char detail[48];
            memcpy(item, p, len);   /* channel_item cut it up */
            snprintf(detail, sizeof detail, "bad channel range '%.20s'", scpi_strip(item));
            return scpi_fail(status, SCPI_DATA_TYPE, detail);
        }
        if (!(1 <= first && first <= last && last <= count)) {
            char detail[40];
            snprintf(detail, sizeof detail, "channels are 1 to %d", count);
            return scpi_fail(status, SCPI_OUT_OF_RANGE, detail);
        }
        for (long c = first; c <= last; c++) {
            repeated |= (seen >> (c - 1)) & 1u;
            seen |= 1u << (c - 1);
            if (total < count)
                indices[total] = (uint8_t)(c - 1);
            total++;
        }
        p = stop + 1;
    }
    if (repeated)
        return scpi_fail(status, SCPI_ILLEGAL_VALUE, "channel listed twice");
    *n = total;
    return SCPI_OK;
}

void scpi_format_number(double value, char *out, size_t size)
{
    if (isfinite(value) && value == floor(value) && fabs(value) < 1e16) {
        snprintf(out, size, "%.0f", value);
        if (!strcmp(out, "-0"))
            snprintf(out, size, "0");
        return;
    }
    for (int digits = 1; digits <= 17; digits++) {
        snprintf(out, size, "%.*g", digits, value);
        if (strtod(out, NULL) == value)
            return;
    }
}
