/*
 * imu_link: the device side of the imu-station native protocol, version 1 (see imu_link.h).
 */
#include "imu_link.h"

#include <string.h>

/* The sample encoder copies floats bit for bit: the protocol's floats are IEEE-754 binary32. */
typedef char imu_link_float_is_32_bits[(sizeof(float) == 4u) ? 1 : -1];
/* The ring's free-running indices must tell a full queue from an empty one: at most half their range. */
typedef char imu_link_ring_size_is_a_power_of_two[
    (IMU_LINK_RING_SIZE >= 2u && IMU_LINK_RING_SIZE <= 32768u &&
     IMU_LINK_RING_SIZE <= (size_t)(imu_link_ring_index_t)-1 / 2u + 1u &&
     (IMU_LINK_RING_SIZE & (IMU_LINK_RING_SIZE - 1u)) == 0u) ? 1 : -1];
typedef char imu_link_rx_max_payload_in_range[
    (IMU_LINK_RX_MAX_PAYLOAD >= 2u && IMU_LINK_RX_MAX_PAYLOAD <= IMU_LINK_MAX_PAYLOAD) ? 1 : -1];

#define SYNC0 0xA5u
#define SYNC1 0x5Au
#define HEADER_SIZE 5u
#define CRC_SIZE 2u
#define RX_CAPACITY (IMU_LINK_RX_MAX_PAYLOAD + IMU_LINK_OVERHEAD)

/* Counts the bytes the parser's CRCs cover: a no-op, defined by tests/resync_cost.c to measure the
   resync's worst case stated in imu_link.h. */
#ifndef IMU_LINK_COUNT_CRC
#define IMU_LINK_COUNT_CRC(bytes) ((void)0)
#endif

/* ---- CRC-16/CCITT-FALSE ------------------------------------------------------------------- */

/* A nibble table: 32 bytes of flash, half the steps of the bitwise loop. */
static const uint16_t crc_nibble[16] = {
    0x0000u, 0x1021u, 0x2042u, 0x3063u, 0x4084u, 0x50A5u, 0x60C6u, 0x70E7u,
    0x8108u, 0x9129u, 0xA14Au, 0xB16Bu, 0xC18Cu, 0xD1ADu, 0xE1CEu, 0xF1EFu,
};

static uint16_t crc_update(uint16_t crc, const uint8_t *data, size_t len)
{
    size_t i;
    for (i = 0; i < len; i++) {
        crc = (uint16_t)((crc << 4) ^ crc_nibble[((crc >> 12) ^ (data[i] >> 4)) & 0x0Fu]);
        crc = (uint16_t)((crc << 4) ^ crc_nibble[((crc >> 12) ^ data[i]) & 0x0Fu]);
    }
    return crc;
}

uint16_t imu_link_crc16(const uint8_t *data, size_t len)
{
    return crc_update(0xFFFFu, data, len);
}

/* ---- encoders ------------------------------------------------------------------------------ */

static void put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

static void put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    p[2] = (uint8_t)(v >> 16);
    p[3] = (uint8_t)(v >> 24);
}

static void put_f32(uint8_t *p, float f)
{
    uint32_t bits;
    memcpy(&bits, &f, sizeof bits);
    put_u32(p, bits);
}

/* Sync, id and length in front of a payload already at buf + HEADER_SIZE, then its CRC. */
static size_t seal_frame(uint8_t *buf, uint8_t id, size_t len)
{
    buf[0] = SYNC0;
    buf[1] = SYNC1;
    buf[2] = id;
    put_u16(buf + 3, (uint16_t)len);
    put_u16(buf + HEADER_SIZE + len, imu_link_crc16(buf + 2, 3u + len));
    return len + IMU_LINK_OVERHEAD;
}

size_t imu_link_encode_frame(uint8_t *buf, size_t cap, uint8_t id, const uint8_t *payload, size_t len)
{
    if (len > IMU_LINK_MAX_PAYLOAD || cap < len + IMU_LINK_OVERHEAD) {
        return 0;
    }
    if (len > 0u) {
        memmove(buf + HEADER_SIZE, payload, len);
    }
    return seal_frame(buf, id, len);
}

size_t imu_link_encode_sample(uint8_t *buf, size_t cap, const imu_link_sample_t *s)
{
    size_t len = s->has_mag ? 52u : 40u;
    uint8_t *p = buf + HEADER_SIZE;
    int i;
    if (cap < len + IMU_LINK_OVERHEAD) {
        return 0;
    }
    put_u32(p, s->seq);
    put_u32(p + 4, (uint32_t)s->t_us);
    put_u32(p + 8, (uint32_t)(s->t_us >> 32));
    for (i = 0; i < 3; i++) {
        put_f32(p + 12 + 4 * i, s->acc[i]);
        put_f32(p + 24 + 4 * i, s->gyro[i]);
    }
    put_f32(p + 36, s->temp);
    if (s->has_mag) {
        for (i = 0; i < 3; i++) {
            put_f32(p + 40 + 4 * i, s->mag[i]);
        }
    }
    return seal_frame(buf, s->has_mag ? IMU_LINK_IMU_MAG_SAMPLE : IMU_LINK_IMU_SAMPLE, len);
}

size_t imu_link_encode_ack(uint8_t *buf, size_t cap, uint8_t command_id, uint8_t status)
{
    if (cap < 2u + IMU_LINK_OVERHEAD) {
        return 0;
    }
    buf[HEADER_SIZE] = command_id;
    buf[HEADER_SIZE + 1u] = status;
    return seal_frame(buf, IMU_LINK_ACK, 2u);
}

/* Appends to a bounded payload; `len` runs past `cap` when it does not fit, which the caller
   checks once at the end instead of after every byte. */
typedef struct {
    uint8_t *buf;
    size_t cap;
    size_t len;
} writer_t;

static void emit(writer_t *w, const char *text, size_t n)
{
    if (w->len + n <= w->cap) {
        memcpy(w->buf + w->len, text, n);
    }
    w->len += n;
}

static void emit_literal(writer_t *w, const char *text)
{
    emit(w, text, strlen(text));
}

/* Length of the well-formed UTF-8 sequence at s (RFC 3629: no overlongs, no surrogates, nothing
   above U+10FFFF), or 0 when the bytes there are not one. */
static size_t utf8_sequence(const uint8_t *s)
{
    uint8_t c = s[0];
    uint8_t lo = 0x80u, hi = 0xBFu;
    size_t n, i;
    if (c < 0x80u) {
        return 1;
    }
    if (c >= 0xC2u && c <= 0xDFu) {
        n = 2;
    } else if (c >= 0xE0u && c <= 0xEFu) {
        n = 3;
        lo = (c == 0xE0u) ? 0xA0u : 0x80u;
        hi = (c == 0xEDu) ? 0x9Fu : 0xBFu;
    } else if (c >= 0xF0u && c <= 0xF4u) {
        n = 4;
        lo = (c == 0xF0u) ? 0x90u : 0x80u;
        hi = (c == 0xF4u) ? 0x8Fu : 0xBFu;
    } else {
        return 0;
    }
    if (s[1] < lo || s[1] > hi) {
        return 0;
    }
    for (i = 2; i < n; i++) {  /* a NUL terminator fails this test before anything is read past it */
        if (s[i] < 0x80u || s[i] > 0xBFu) {
            return 0;
        }
    }
    return n;
}

/* A JSON string, escaped as Python's json.dumps escapes ASCII, so that the station's own encoder
   writes the same bytes. Bytes that are not UTF-8 become U+FFFD: the payload stays valid UTF-8.
   A null pointer is an empty string. */
static void emit_json_string(writer_t *w, const char *text)
{
    static const char hex[] = "0123456789abcdef";
    const uint8_t *s = (const uint8_t *)(text ? text : "");
    emit(w, "\"", 1);
    while (*s != 0u) {
        uint8_t c = *s;
        size_t n = utf8_sequence(s);
        if (n == 0u) {
            emit_literal(w, "\\ufffd");
            s++;
            continue;
        }
        if (c == '"' || c == '\\') {
            char esc[2];
            esc[0] = '\\';
            esc[1] = (char)c;
            emit(w, esc, 2);
        } else if (c == '\n') {
            emit_literal(w, "\\n");
        } else if (c == '\r') {
            emit_literal(w, "\\r");
        } else if (c == '\t') {
            emit_literal(w, "\\t");
        } else if (c == '\b') {
            emit_literal(w, "\\b");
        } else if (c == '\f') {
            emit_literal(w, "\\f");
        } else if (c < 0x20u) {
            char esc[6];
            esc[0] = '\\';
            esc[1] = 'u';
            esc[2] = '0';
            esc[3] = '0';
            esc[4] = hex[c >> 4];
            esc[5] = hex[c & 0x0Fu];
            emit(w, esc, 6);
        } else {
            emit(w, (const char *)s, n);
        }
        s += n;
    }
    emit(w, "\"", 1);
}

static void emit_uint(writer_t *w, uint16_t v)
{
    char digits[5];
    size_t n = 0;
    do {
        digits[sizeof digits - 1u - n] = (char)('0' + v % 10u);
        v = (uint16_t)(v / 10u);
        n++;
    } while (v != 0u);
    emit(w, digits + sizeof digits - n, n);
}

size_t imu_link_encode_info(uint8_t *buf, size_t cap, const char *serial, const char *model,
                            const char *firmware, uint16_t rate_hz)
{
    writer_t w;
    if (cap < IMU_LINK_OVERHEAD) {
        return 0;
    }
    w.buf = buf + HEADER_SIZE;
    w.cap = cap - IMU_LINK_OVERHEAD;
    if (w.cap > IMU_LINK_MAX_PAYLOAD) {
        w.cap = IMU_LINK_MAX_PAYLOAD;
    }
    w.len = 0;
    emit_literal(&w, "{\"serial\":");
    emit_json_string(&w, serial);
    emit_literal(&w, ",\"model\":");
    emit_json_string(&w, model);
    emit_literal(&w, ",\"firmware\":");
    emit_json_string(&w, firmware);
    emit_literal(&w, ",\"rate_hz\":");
    emit_uint(&w, rate_hz);
    emit(&w, "}", 1);
    if (w.len > w.cap) {
        return 0;
    }
    return seal_frame(buf, IMU_LINK_DEVICE_INFO, w.len);
}

/* ---- parser --------------------------------------------------------------------------------- */

void imu_link_parser_init(imu_link_parser_t *p)
{
    p->head = 0;
    p->tail = 0;
    p->errors = 0;
    p->in_garbage = 0;
}

uint32_t imu_link_parser_errors(const imu_link_parser_t *p)
{
    return p->errors;
}

/* Bytes skipped outside any frame: one error per run of them, however long. */
static void skip_garbage(imu_link_parser_t *p, uint16_t count)
{
    if (!p->in_garbage) {
        p->errors++;
        p->in_garbage = 1;
    }
    p->head = (uint16_t)(p->head + count);
}

/* A candidate frame at head failed (absurd length, bad CRC): count it, and search again from the
   byte after its sync, so a good frame inside the bytes it claimed is still found. */
static void reject_candidate(imu_link_parser_t *p)
{
    p->errors++;
    p->in_garbage = 1;
    p->head++;
}

static void fill_command(const uint8_t *frame, uint16_t length, imu_link_command_t *cmd)
{
    uint16_t kept = length < sizeof cmd->payload ? length : (uint16_t)sizeof cmd->payload;
    cmd->id = frame[2];
    cmd->length = length;
    memset(cmd->payload, 0, sizeof cmd->payload);
    memcpy(cmd->payload, frame + HEADER_SIZE, kept);
    cmd->rate_hz = 0;
    if (cmd->id == IMU_LINK_SET_RATE && length == 2u) {
        cmd->rate_hz = (uint16_t)(frame[HEADER_SIZE] | (frame[HEADER_SIZE + 1u] << 8));
    }
}

int imu_link_parser_next(imu_link_parser_t *p, imu_link_command_t *cmd)
{
    for (;;) {
        const uint8_t *b = p->buf + p->head;
        uint16_t n = (uint16_t)(p->tail - p->head);
        uint16_t length;
        size_t end;
        if (n == 0u) {
            return 0;
        }
        if (b[0] != SYNC0) {
            const uint8_t *next = memchr(b + 1, SYNC0, (size_t)n - 1u);
            skip_garbage(p, next ? (uint16_t)(next - b) : n);
            continue;
        }
        if (n < 2u) {
            return 0;
        }
        if (b[1] != SYNC1) {
            skip_garbage(p, 1);
            continue;
        }
        if (n < HEADER_SIZE) {
            return 0;
        }
        length = (uint16_t)(b[3] | (b[4] << 8));
        if (length > IMU_LINK_RX_MAX_PAYLOAD) {
            reject_candidate(p);
            continue;
        }
        end = (size_t)length + IMU_LINK_OVERHEAD;
        if (n < end) {
            return 0;
        }
        IMU_LINK_COUNT_CRC(3u + (size_t)length);
        if (imu_link_crc16(b + 2, 3u + (size_t)length) !=
            (uint16_t)(b[end - 2u] | (b[end - 1u] << 8))) {
            reject_candidate(p);
            continue;
        }
        fill_command(b, length, cmd);
        p->head = (uint16_t)(p->head + end);
        p->in_garbage = 0;
        return 1;
    }
}

int imu_link_parse_byte(imu_link_parser_t *p, uint8_t byte, imu_link_command_t *cmd)
{
    if (p->head == p->tail) {
        p->head = 0;
        p->tail = 0;
    } else if (p->tail == RX_CAPACITY) {
        /* Unresolved bytes never fill the buffer (a frame is resolved once its last byte is in),
           so moving them to the front always leaves room for this one. */
        memmove(p->buf, p->buf + p->head, (size_t)(p->tail - p->head));
        p->tail = (uint16_t)(p->tail - p->head);
        p->head = 0;
    }
    p->buf[p->tail++] = byte;
    return imu_link_parser_next(p, cmd);
}

/* ---- interrupt-to-main-loop queue ---------------------------------------------------------- */

void imu_link_ring_init(imu_link_ring_t *r)
{
    r->head = 0;
    r->tail = 0;
    r->dropped = 0;
}

int imu_link_ring_put(imu_link_ring_t *r, uint8_t byte)
{
    imu_link_ring_index_t head = r->head;
    if ((imu_link_ring_index_t)(head - r->tail) >= IMU_LINK_RING_SIZE) {
        r->dropped++;
        return 0;
    }
    r->data[head & (IMU_LINK_RING_SIZE - 1u)] = byte;
    r->head = (imu_link_ring_index_t)(head + 1u);  /* published after the byte: both volatile, so in order */
    return 1;
}

int imu_link_ring_get(imu_link_ring_t *r, uint8_t *byte)
{
    imu_link_ring_index_t tail = r->tail;
    if (r->head == tail) {
        return 0;
    }
    *byte = r->data[tail & (IMU_LINK_RING_SIZE - 1u)];
    r->tail = (imu_link_ring_index_t)(tail + 1u);
    return 1;
}
