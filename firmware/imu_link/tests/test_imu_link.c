/*
 * Unit tests of imu_link, with a plain runner: each test prints its name when it fails, and the
 * last line reads "N passed, N failed". The exit status is 1 when any test failed.
 */
#include "../imu_link.h"

#include <stdio.h>
#include <string.h>

static int current_failed;

#define CHECK(cond)                                                                  \
    do {                                                                             \
        if (!(cond)) {                                                               \
            printf("  %s:%d: CHECK(%s) failed\n", __FILE__, __LINE__, #cond);        \
            current_failed = 1;                                                      \
        }                                                                            \
    } while (0)

/* A frame built independently of the library's encoders: its bytes by hand, its CRC bitwise. */
static uint16_t crc_bitwise(const uint8_t *data, size_t len)
{
    uint16_t crc = 0xFFFFu;
    size_t i;
    int bit;
    for (i = 0; i < len; i++) {
        crc = (uint16_t)(crc ^ (data[i] << 8));
        for (bit = 0; bit < 8; bit++) {
            crc = (uint16_t)((crc & 0x8000u) ? ((unsigned)crc << 1) ^ 0x1021u : (unsigned)crc << 1);
        }
    }
    return crc;
}

static size_t hand_frame(uint8_t *out, uint8_t id, const uint8_t *payload, uint16_t len)
{
    uint16_t crc;
    out[0] = 0xA5;
    out[1] = 0x5A;
    out[2] = id;
    out[3] = (uint8_t)len;
    out[4] = (uint8_t)(len >> 8);
    if (len) {
        memcpy(out + 5, payload, len);
    }
    crc = crc_bitwise(out + 2, 3u + len);
    out[5 + len] = (uint8_t)crc;
    out[6 + len] = (uint8_t)(crc >> 8);
    return 7u + len;
}

/* Feeds bytes one at a time; collects every command, including those imu_link_parser_next hands over. */
static size_t feed(imu_link_parser_t *p, const uint8_t *bytes, size_t n, imu_link_command_t *out, size_t max)
{
    size_t i, got = 0;
    imu_link_command_t cmd;
    for (i = 0; i < n; i++) {
        if (imu_link_parse_byte(p, bytes[i], &cmd)) {
            do {
                if (got < max) {
                    out[got] = cmd;
                }
                got++;
            } while (imu_link_parser_next(p, &cmd));
        }
    }
    return got;
}

static float f32_at(const uint8_t *p)
{
    uint32_t bits = (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
    float f;
    memcpy(&f, &bits, sizeof f);
    return f;
}

/* ---- CRC ------------------------------------------------------------------------------------ */

static void test_crc_check_value(void)
{
    CHECK(imu_link_crc16((const uint8_t *)"123456789", 9) == 0x29B1u);
    CHECK(imu_link_crc16((const uint8_t *)"", 0) == 0xFFFFu);
}

static void test_crc_agrees_with_the_bitwise_definition(void)
{
    uint8_t data[256];
    size_t i;
    for (i = 0; i < sizeof data; i++) {
        data[i] = (uint8_t)(i * 37u + 11u);
    }
    for (i = 0; i <= sizeof data; i += 17) {
        CHECK(imu_link_crc16(data, i) == crc_bitwise(data, i));
    }
}

/* ---- encoders ------------------------------------------------------------------------------- */

static imu_link_sample_t a_sample(void)
{
    imu_link_sample_t s;
    memset(&s, 0, sizeof s);
    s.seq = 0xFFFFFFFEu;
    s.t_us = 0x0000000123456789ull;
    s.acc[0] = 0.125f;
    s.acc[1] = -0.5f;
    s.acc[2] = 9.80665f;
    s.gyro[0] = 1e-3f;
    s.gyro[1] = -2e-3f;
    s.gyro[2] = 3.5f;
    s.temp = 25.25f;
    s.mag[0] = 20.0f;
    s.mag[1] = -5.0f;
    s.mag[2] = 42.0f;
    return s;
}

static void test_sample_frame_layout(void)
{
    imu_link_sample_t s = a_sample();
    uint8_t buf[64], expected[64], payload[40];
    size_t n;
    int i;
    memset(payload, 0, sizeof payload);
    payload[0] = 0xFE; payload[1] = 0xFF; payload[2] = 0xFF; payload[3] = 0xFF;
    payload[4] = 0x89; payload[5] = 0x67; payload[6] = 0x45; payload[7] = 0x23;
    payload[8] = 0x01;
    for (i = 0; i < 3; i++) {
        memcpy(payload + 12 + 4 * i, &s.acc[i], 4);   /* the test host is little-endian */
        memcpy(payload + 24 + 4 * i, &s.gyro[i], 4);
    }
    memcpy(payload + 36, &s.temp, 4);
    n = imu_link_encode_sample(buf, sizeof buf, &s);
    CHECK(n == IMU_LINK_SAMPLE_FRAME_SIZE);
    CHECK(hand_frame(expected, 0x01, payload, 40) == n);
    CHECK(memcmp(buf, expected, n) == 0);
    CHECK(f32_at(buf + 5 + 20) == 9.80665f);
}

static void test_mag_sample_frame_appends_the_field(void)
{
    imu_link_sample_t s = a_sample();
    uint8_t plain[64], mag[64];
    s.has_mag = 1;
    CHECK(imu_link_encode_sample(mag, sizeof mag, &s) == IMU_LINK_MAG_SAMPLE_FRAME_SIZE);
    s.has_mag = 0;
    CHECK(imu_link_encode_sample(plain, sizeof plain, &s) == IMU_LINK_SAMPLE_FRAME_SIZE);
    CHECK(mag[2] == IMU_LINK_IMU_MAG_SAMPLE && mag[3] == 52 && mag[4] == 0);
    CHECK(memcmp(mag + 5, plain + 5, 40) == 0);
    CHECK(f32_at(mag + 45) == 20.0f && f32_at(mag + 49) == -5.0f && f32_at(mag + 53) == 42.0f);
    CHECK(imu_link_crc16(mag + 2, 55) == (uint16_t)(mag[57] | (mag[58] << 8)));
}

/* An encoder given too little room returns 0 and writes nothing past cap. */
static void test_encoders_refuse_a_short_buffer_without_overrun(void)
{
    imu_link_sample_t s = a_sample();
    uint8_t buf[80];
    size_t cap;
    int clean = 1;
    for (cap = 0; cap < IMU_LINK_SAMPLE_FRAME_SIZE; cap++) {
        memset(buf, 0xEE, sizeof buf);
        CHECK(imu_link_encode_sample(buf, cap, &s) == 0);
        CHECK(imu_link_encode_ack(buf, cap < 9 ? cap : 8, 0x11, 0) == 0);
        CHECK(imu_link_encode_info(buf, cap, "S1", "M", "F", 200) == 0);
        clean &= buf[cap] == 0xEE;
    }
    CHECK(clean);
    s.has_mag = 1;
    CHECK(imu_link_encode_sample(buf, IMU_LINK_MAG_SAMPLE_FRAME_SIZE - 1u, &s) == 0);
    CHECK(imu_link_encode_ack(buf, 9, 0x11, 0) == 9);
}

static void test_ack_frame(void)
{
    uint8_t buf[16], expected[16];
    const uint8_t payload[2] = {0x11, 2};
    CHECK(imu_link_encode_ack(buf, sizeof buf, 0x11, 2) == 9);
    hand_frame(expected, 0x03, payload, 2);
    CHECK(memcmp(buf, expected, 9) == 0);
}

static int info_payload_is(const char *serial, const char *model, const char *firmware, uint16_t rate,
                           const char *json)
{
    uint8_t buf[1100], expected[1100];
    size_t n = imu_link_encode_info(buf, sizeof buf, serial, model, firmware, rate);
    size_t m = hand_frame(expected, 0x02, (const uint8_t *)json, (uint16_t)strlen(json));
    if (n != m || memcmp(buf, expected, n) != 0) {
        printf("  got %.*s\n", (int)(n > 7 ? n - 7 : 0), (const char *)buf + 5);
        return 0;
    }
    return 1;
}

static void test_info_is_compact_json(void)
{
    CHECK(info_payload_is("SN-1", "imu", "1.0", 200,
                          "{\"serial\":\"SN-1\",\"model\":\"imu\",\"firmware\":\"1.0\",\"rate_hz\":200}"));
    CHECK(info_payload_is("", "", "", 0, "{\"serial\":\"\",\"model\":\"\",\"firmware\":\"\",\"rate_hz\":0}"));
    CHECK(info_payload_is("a", "b", "c", 65535, "{\"serial\":\"a\",\"model\":\"b\",\"firmware\":\"c\",\"rate_hz\":65535}"));
    CHECK(info_payload_is(NULL, "b", "c", 7, "{\"serial\":\"\",\"model\":\"b\",\"firmware\":\"c\",\"rate_hz\":7}"));
}

static void test_info_escapes_as_json(void)
{
    CHECK(info_payload_is("q\"b\\s/", "t\tn\nr\rb\bf\f", "\x01\x1f\x7f", 1,
                          "{\"serial\":\"q\\\"b\\\\s/\",\"model\":\"t\\tn\\nr\\rb\\bf\\f\","
                          "\"firmware\":\"\\u0001\\u001f\x7f\",\"rate_hz\":1}"));
}

static void test_info_keeps_utf8_and_replaces_what_is_not(void)
{
    /* e-acute, a euro sign, a 4-byte emoji pass through; a lone continuation byte, an overlong
       slash, a surrogate and a truncated sequence become U+FFFD, one per byte refused. */
    CHECK(info_payload_is("\xc3\xa9\xe2\x82\xac\xf0\x9f\x98\x80", "\x80", "\xc0\xaf\xed\xa0\x80\xe2\x82", 5,
                          "{\"serial\":\"\xc3\xa9\xe2\x82\xac\xf0\x9f\x98\x80\",\"model\":\"\\ufffd\","
                          "\"firmware\":\"\\ufffd\\ufffd\\ufffd\\ufffd\\ufffd\\ufffd\\ufffd\",\"rate_hz\":5}"));
}

static void test_info_longer_than_the_protocol_allows_is_refused(void)
{
    static char serial[1100];
    static uint8_t buf[1200];
    size_t fixed = strlen("{\"serial\":\"\",\"model\":\"m\",\"firmware\":\"f\",\"rate_hz\":1}");
    memset(serial, 'x', sizeof serial - 1u);
    serial[1024 - fixed] = 0;
    CHECK(imu_link_encode_info(buf, sizeof buf, serial, "m", "f", 1) == 1024u + 7u);
    serial[1024 - fixed] = 'x';
    serial[1024 - fixed + 1u] = 0;
    CHECK(imu_link_encode_info(buf, sizeof buf, serial, "m", "f", 1) == 0);
}

static void test_encode_frame_carries_any_payload(void)
{
    uint8_t buf[32], expected[32];
    const uint8_t payload[3] = {1, 2, 3};
    CHECK(imu_link_encode_frame(buf, sizeof buf, 0x20, payload, 3) == 10);
    hand_frame(expected, 0x20, payload, 3);
    CHECK(memcmp(buf, expected, 10) == 0);
    CHECK(imu_link_encode_frame(buf, 9, 0x20, payload, 3) == 0);
    CHECK(imu_link_encode_frame(buf, sizeof buf, 0x12, NULL, 0) == 7);
}

/* ---- parser --------------------------------------------------------------------------------- */

static void test_parses_each_command(void)
{
    imu_link_parser_t p;
    imu_link_command_t cmds[8];
    uint8_t stream[64];
    const uint8_t rate[2] = {0x90, 0x01};
    size_t n = 0;
    n += hand_frame(stream + n, 0x10, NULL, 0);
    n += hand_frame(stream + n, 0x11, rate, 2);
    n += hand_frame(stream + n, 0x12, NULL, 0);
    n += hand_frame(stream + n, 0x13, NULL, 0);
    n += hand_frame(stream + n, 0x14, NULL, 0);
    imu_link_parser_init(&p);
    CHECK(feed(&p, stream, n, cmds, 8) == 5);
    CHECK(cmds[0].id == 0x10 && cmds[0].length == 0);
    CHECK(cmds[1].id == 0x11 && cmds[1].length == 2 && cmds[1].rate_hz == 400);
    CHECK(cmds[2].id == 0x12 && cmds[3].id == 0x13 && cmds[4].id == 0x14);
    CHECK(cmds[4].rate_hz == 0);
    CHECK(imu_link_parser_errors(&p) == 0);
}

static void test_returns_1_on_the_last_byte_only(void)
{
    imu_link_parser_t p;
    imu_link_command_t cmd;
    uint8_t frame[16];
    size_t n = hand_frame(frame, 0x10, NULL, 0), i;
    int early = 0;
    imu_link_parser_init(&p);
    for (i = 0; i + 1 < n; i++) {
        early |= imu_link_parse_byte(&p, frame[i], &cmd);
    }
    CHECK(!early);
    CHECK(imu_link_parse_byte(&p, frame[n - 1], &cmd) == 1);
    CHECK(imu_link_parser_next(&p, &cmd) == 0);
}

static void test_set_rate_with_a_wrong_length_has_no_rate(void)
{
    imu_link_parser_t p;
    imu_link_command_t cmds[2];
    uint8_t stream[32];
    const uint8_t arg[3] = {100, 0, 0};
    size_t n = hand_frame(stream, 0x11, arg, 1);
    n += hand_frame(stream + n, 0x11, arg, 3);
    imu_link_parser_init(&p);
    CHECK(feed(&p, stream, n, cmds, 2) == 2);
    CHECK(cmds[0].length == 1 && cmds[0].rate_hz == 0 && cmds[0].payload[0] == 100);
    CHECK(cmds[1].length == 3 && cmds[1].rate_hz == 0);
}

static void test_long_payload_keeps_its_first_64_bytes(void)
{
    imu_link_parser_t p;
    imu_link_command_t cmd[1];
    static uint8_t payload[1024], stream[1100];
    size_t i, n;
    for (i = 0; i < sizeof payload; i++) {
        payload[i] = (uint8_t)(i ^ 0x5Cu);
    }
    n = hand_frame(stream, 0x30, payload, 1024);
    imu_link_parser_init(&p);
    CHECK(feed(&p, stream, n, cmd, 1) == 1);
    CHECK(cmd[0].id == 0x30 && cmd[0].length == 1024 && memcmp(cmd[0].payload, payload, 64) == 0);
}

static void test_garbage_before_and_between_is_one_error_per_run(void)
{
    imu_link_parser_t p;
    imu_link_command_t cmds[4];
    uint8_t stream[64];
    size_t n = 0;
    memcpy(stream, "junk\xa5!", 6);
    n = 6;
    n += hand_frame(stream + n, 0x10, NULL, 0);
    memcpy(stream + n, "\xa5\xa5 more", 7);
    n += 7;
    n += hand_frame(stream + n, 0x12, NULL, 0);
    imu_link_parser_init(&p);
    CHECK(feed(&p, stream, n, cmds, 4) == 2);
    CHECK(cmds[0].id == 0x10 && cmds[1].id == 0x12);
    CHECK(imu_link_parser_errors(&p) == 2);
}

static void test_sync_split_by_a_false_first_byte(void)
{
    imu_link_parser_t p;
    imu_link_command_t cmds[2];
    uint8_t stream[16];
    stream[0] = 0xA5;
    imu_link_parser_init(&p);
    CHECK(feed(&p, stream, hand_frame(stream + 1, 0x13, NULL, 0) + 1, cmds, 2) == 1);
    CHECK(cmds[0].id == 0x13 && imu_link_parser_errors(&p) == 1);
}

static void test_bad_crc_is_skipped_and_counted(void)
{
    imu_link_parser_t p;
    imu_link_command_t cmds[2];
    uint8_t stream[32];
    size_t n = hand_frame(stream, 0x10, NULL, 0);
    stream[5] ^= 1;
    n += hand_frame(stream + n, 0x12, NULL, 0);
    imu_link_parser_init(&p);
    CHECK(feed(&p, stream, n, cmds, 2) == 1);
    CHECK(cmds[0].id == 0x12 && imu_link_parser_errors(&p) == 1);
}

static void test_absurd_length_is_skipped_at_once(void)
{
    imu_link_parser_t p;
    imu_link_command_t cmds[2];
    uint8_t stream[32] = {0xA5, 0x5A, 0x10, 0x01, 0x04};  /* L = 1025 */
    size_t n = 5 + hand_frame(stream + 5, 0x13, NULL, 0);
    imu_link_parser_init(&p);
    CHECK(feed(&p, stream, n, cmds, 2) == 1);
    CHECK(cmds[0].id == 0x13 && imu_link_parser_errors(&p) == 1);
}

/* A damaged frame whose length claims the next commands: they are found once its CRC fails, the
   two that the same byte completes included. */
static void test_commands_inside_a_damaged_frame_are_not_lost(void)
{
    imu_link_parser_t p;
    imu_link_command_t cmds[4];
    uint8_t stream[64] = {0xA5, 0x5A, 0x10, 14, 0};
    const uint8_t rate[2] = {50, 0};
    size_t n = 5;
    n += hand_frame(stream + n, 0x12, NULL, 0);
    n += hand_frame(stream + n, 0x13, NULL, 0);
    stream[n++] = 0x00;  /* the claimed frame's CRC: wrong */
    stream[n++] = 0x00;
    n += hand_frame(stream + n, 0x11, rate, 2);
    imu_link_parser_init(&p);
    CHECK(feed(&p, stream, n, cmds, 4) == 3);
    CHECK(cmds[0].id == 0x12 && cmds[1].id == 0x13 && cmds[2].id == 0x11 && cmds[2].rate_hz == 50);
    CHECK(imu_link_parser_errors(&p) == 2);  /* the damaged frame, then its two stray CRC bytes */
}

/* A frame cut short by the next one (a device reset mid-frame): what follows survives, even when
   the cut frame claimed more bytes than the next three commands hold. */
static void test_truncated_frame_loses_nothing_after_it(void)
{
    imu_link_parser_t p;
    imu_link_command_t cmds[4];
    uint8_t stream[64], payload[20];
    const uint8_t rate[2] = {0xE8, 0x03};
    size_t n = hand_frame(stream, 0x11, rate, 2) - 3;
    n += hand_frame(stream + n, 0x10, NULL, 0);
    imu_link_parser_init(&p);
    CHECK(feed(&p, stream, n, cmds, 4) == 1);
    CHECK(cmds[0].id == 0x10 && imu_link_parser_errors(&p) == 1);

    memset(payload, 0, sizeof payload);
    n = hand_frame(stream, 0x20, payload, 20) - 19;
    n += hand_frame(stream + n, 0x10, NULL, 0);
    n += hand_frame(stream + n, 0x12, NULL, 0);
    CHECK(feed(&p, stream, n, cmds, 4) == 0);  /* still waiting for the cut frame's claimed bytes */
    n = hand_frame(stream, 0x13, NULL, 0);
    CHECK(feed(&p, stream, n, cmds, 4) == 3);  /* its last byte completes the claim and three frames */
    CHECK(cmds[0].id == 0x10 && cmds[1].id == 0x12 && cmds[2].id == 0x13);
    CHECK(imu_link_parser_errors(&p) == 2);
}

/* Long streams wrap the parser's buffer many times over. */
static void test_long_stream_of_mixed_frames(void)
{
    imu_link_parser_t p;
    imu_link_command_t cmds[1];
    static uint8_t payload[700], stream[800];
    size_t round, n, total = 0, expected = 0;
    imu_link_parser_init(&p);
    for (round = 0; round < 200; round++) {
        uint16_t len = (uint16_t)((round * 97u) % 700u);
        memset(payload, (int)round, len);
        n = hand_frame(stream, (uint8_t)(0x10 + round % 5u), payload, len);
        if (round % 7u == 3u) {
            stream[n / 2u] ^= 0x40;
        } else {
            expected++;
        }
        total += feed(&p, stream, n, cmds, 1);
    }
    CHECK(total == expected);
}

/* ---- ring --------------------------------------------------------------------------------- */

static void test_ring_keeps_order_and_counts_overflow(void)
{
    imu_link_ring_t r;
    uint8_t b = 0;
    unsigned i, ok = 1;
    imu_link_ring_init(&r);
    CHECK(imu_link_ring_get(&r, &b) == 0);
    for (i = 0; i < IMU_LINK_RING_SIZE + 3u; i++) {
        imu_link_ring_put(&r, (uint8_t)i);
    }
    CHECK(r.dropped == 3);
    for (i = 0; i < IMU_LINK_RING_SIZE; i++) {
        ok &= imu_link_ring_get(&r, &b) == 1 && b == (uint8_t)i;
    }
    CHECK(ok);
    CHECK(imu_link_ring_get(&r, &b) == 0);
    for (i = 0; i < 70000u; i++) {  /* the indices wrap their 16 bits */
        ok &= imu_link_ring_put(&r, (uint8_t)(i * 7u)) == 1;
        ok &= imu_link_ring_get(&r, &b) == 1 && b == (uint8_t)(i * 7u);
    }
    CHECK(ok);
}

typedef void (*test_fn)(void);

static const struct {
    const char *name;
    test_fn fn;
} tests[] = {
    {"crc_check_value", test_crc_check_value},
    {"crc_agrees_with_the_bitwise_definition", test_crc_agrees_with_the_bitwise_definition},
    {"sample_frame_layout", test_sample_frame_layout},
    {"mag_sample_frame_appends_the_field", test_mag_sample_frame_appends_the_field},
    {"encoders_refuse_a_short_buffer_without_overrun", test_encoders_refuse_a_short_buffer_without_overrun},
    {"ack_frame", test_ack_frame},
    {"info_is_compact_json", test_info_is_compact_json},
    {"info_escapes_as_json", test_info_escapes_as_json},
    {"info_keeps_utf8_and_replaces_what_is_not", test_info_keeps_utf8_and_replaces_what_is_not},
    {"info_longer_than_the_protocol_allows_is_refused", test_info_longer_than_the_protocol_allows_is_refused},
    {"encode_frame_carries_any_payload", test_encode_frame_carries_any_payload},
    {"parses_each_command", test_parses_each_command},
    {"returns_1_on_the_last_byte_only", test_returns_1_on_the_last_byte_only},
    {"set_rate_with_a_wrong_length_has_no_rate", test_set_rate_with_a_wrong_length_has_no_rate},
    {"long_payload_keeps_its_first_64_bytes", test_long_payload_keeps_its_first_64_bytes},
    {"garbage_before_and_between_is_one_error_per_run", test_garbage_before_and_between_is_one_error_per_run},
    {"sync_split_by_a_false_first_byte", test_sync_split_by_a_false_first_byte},
    {"bad_crc_is_skipped_and_counted", test_bad_crc_is_skipped_and_counted},
    {"absurd_length_is_skipped_at_once", test_absurd_length_is_skipped_at_once},
    {"commands_inside_a_damaged_frame_are_not_lost", test_commands_inside_a_damaged_frame_are_not_lost},
    {"truncated_frame_loses_nothing_after_it", test_truncated_frame_loses_nothing_after_it},
    {"long_stream_of_mixed_frames", test_long_stream_of_mixed_frames},
    {"ring_keeps_order_and_counts_overflow", test_ring_keeps_order_and_counts_overflow},
};

int main(void)
{
    size_t i, passed = 0, failed = 0;
    for (i = 0; i < sizeof tests / sizeof tests[0]; i++) {
        current_failed = 0;
        tests[i].fn();
        if (current_failed) {
            printf("FAIL %s\n", tests[i].name);
            failed++;
        } else {
            passed++;
        }
    }
    printf("%lu passed, %lu failed\n", (unsigned long)passed, (unsigned long)failed);
    return failed ? 1 : 0;
}
