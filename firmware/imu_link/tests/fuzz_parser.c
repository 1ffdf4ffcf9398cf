/*
 * Fuzzing of the imu_link parser, meant to run under -fsanitize=address,undefined.
 *
 *   fuzz_parser SEED STREAMS
 *
 * Half the streams are random bytes rich in sync bytes; half are good command frames with bits
 * flipped, bytes inserted and frames cut short. Each stream goes through the parser a byte at a
 * time, and through a reference that applies native-protocol.md's resync rule to the whole
 * stream at once; the two must find the same frames. In the damaged streams, every frame whose
 * bytes were left intact must be found. The last line reads
 * "fuzz: S streams (R random, B bit-flipped), N bytes, C commands, E errors counted, M mismatches,
 * X intact frames missed, F intact frames overlapped by a damaged frame with a matching CRC";
 * the exit status is 1 unless M and X are 0.
 */
#include "../imu_link.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAX_STREAM 8192
#define PADDING (IMU_LINK_MAX_PAYLOAD + IMU_LINK_OVERHEAD)
#define MAX_FRAMES 512

static uint64_t rng_state;

static uint32_t rnd(void)
{
    /* xorshift64*: reproducible from the seed on any platform. */
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return (uint32_t)((rng_state * 2685821657736338717ull) >> 32);
}

static uint32_t below(uint32_t n)
{
    return n ? rnd() % n : 0;
}

typedef struct {
    uint8_t id;
    uint16_t length;
    uint8_t payload[64];
    size_t start;  /* where the frame began in the stream (reference only) */
} found_t;

/* The spec's rule over a whole buffer: at a sync candidate, an invalid length or a bad CRC drops
   the candidate and resumes at the next sync after it; a candidate whose claimed bytes run past
   the end waits (as a live receiver would), and so does everything after it. */
static size_t reference(const uint8_t *s, size_t n, found_t *out, size_t max)
{
    size_t pos = 0, got = 0;
    while (pos + 1 < n) {
        size_t length, end;
        if (!(s[pos] == 0xA5 && s[pos + 1] == 0x5A)) {
            pos++;
            continue;
        }
        if (pos + 5 > n) {
            break;
        }
        length = (size_t)s[pos + 3] | ((size_t)s[pos + 4] << 8);
        if (length > IMU_LINK_RX_MAX_PAYLOAD) {
            pos++;
            continue;
        }
        end = pos + 7 + length;
        if (end > n) {
            break;
        }
        if (imu_link_crc16(s + pos + 2, 3 + length) != (uint16_t)(s[end - 2] | (s[end - 1] << 8))) {
            pos++;
            continue;
        }
        if (got < max) {
            out[got].id = s[pos + 2];
            out[got].length = (uint16_t)length;
            memset(out[got].payload, 0, 64);
            memcpy(out[got].payload, s + pos + 5, length < 64 ? length : 64);
            out[got].start = pos;
        }
        got++;
        pos = end;
    }
    return got;
}

static size_t stream_through_parser(const uint8_t *s, size_t n, found_t *out, size_t max, uint32_t *errors)
{
    static imu_link_parser_t p;  /* static: a large object, as on a board */
    imu_link_command_t cmd;
    size_t i, got = 0;
    imu_link_parser_init(&p);
    for (i = 0; i < n; i++) {
        if (!imu_link_parse_byte(&p, s[i], &cmd)) {
            continue;
        }
        do {
            if (got < max) {
                out[got].id = cmd.id;
                out[got].length = cmd.length;
                memcpy(out[got].payload, cmd.payload, 64);
            }
            got++;
        } while (imu_link_parser_next(&p, &cmd));
    }
    *errors = imu_link_parser_errors(&p);
    return got;
}

static size_t random_stream(uint8_t *s)
{
    size_t n = below(MAX_STREAM), i;
    for (i = 0; i < n; i++) {
        uint32_t r = below(8);
        s[i] = r == 0 ? 0xA5 : r == 1 ? 0x5A : r == 2 ? (uint8_t)below(8) : (uint8_t)rnd();
    }
    return n;
}

typedef struct {
    size_t start, size;
} span_t;

/* Good frames, some long, with garbage between some of them; then damage: flipped bits, cut
   frames; then zeros, enough to settle any frame the damage left waiting for its claimed bytes.
   Returns the stream's length and, in intact[], the frames no damage touched. */
static size_t damaged_stream(uint8_t *s, span_t *intact, size_t *n_intact)
{
    static uint8_t payload[IMU_LINK_MAX_PAYLOAD];
    static span_t frames[MAX_FRAMES];
    static uint8_t touched[MAX_STREAM];
    size_t n = 0, count = 0, i, flips;
    while (count < MAX_FRAMES) {
        size_t len = below(8) == 0 ? below(IMU_LINK_MAX_PAYLOAD + 1) : below(6);
        size_t size;
        for (i = 0; i < len; i++) {
            payload[i] = (uint8_t)rnd();
        }
        if (below(6) == 0) {
            size_t junk = below(12);
            if (n + junk > MAX_STREAM - PADDING) {
                break;
            }
            for (i = 0; i < junk; i++) {
                s[n++] = (uint8_t)(below(3) == 0 ? 0xA5 : rnd());
            }
        }
        if (n + len + IMU_LINK_OVERHEAD > MAX_STREAM - PADDING) {
            break;
        }
        size = imu_link_encode_frame(s + n, MAX_STREAM - n, (uint8_t)(0x10 + below(8)), payload, len);
        if (below(10) == 0) {
            size = below((uint32_t)size);  /* cut short: the next frame follows at once */
            memset(touched + n, 1, size);
        } else {
            memset(touched + n, 0, size);
        }
        frames[count].start = n;
        frames[count].size = size;
        count++;
        n += size;
    }
    flips = below(10);
    for (i = 0; i < flips && n > 0; i++) {
        size_t at = below((uint32_t)n);
        s[at] ^= (uint8_t)(1u << below(8));
        touched[at] = 1;
    }
    memset(s + n, 0, PADDING);
    *n_intact = 0;
    for (i = 0; i < count; i++) {
        size_t k, clean = frames[i].size >= IMU_LINK_OVERHEAD;
        for (k = 0; k < frames[i].size && clean; k++) {
            clean = !touched[frames[i].start + k];
        }
        if (clean && frames[i].size <= IMU_LINK_RX_MAX_PAYLOAD + IMU_LINK_OVERHEAD) {
            intact[(*n_intact)++] = frames[i];
        }
    }
    return n + PADDING;
}

static int same(const found_t *a, const found_t *b)
{
    return a->id == b->id && a->length == b->length && memcmp(a->payload, b->payload, 64) == 0;
}

int main(int argc, char **argv)
{
    static uint8_t stream[MAX_STREAM];
    static found_t got[MAX_FRAMES * 4], want[MAX_FRAMES * 4];
    static span_t intact[MAX_FRAMES];
    unsigned long streams, k, random_streams = 0, damaged_streams = 0;
    unsigned long long bytes = 0, commands = 0, errors = 0, mismatches = 0, missed = 0, forged = 0;
    if (argc != 3) {
        fprintf(stderr, "usage: %s SEED STREAMS\n", argv[0]);
        return 2;
    }
    rng_state = strtoull(argv[1], NULL, 10) * 0x9E3779B97F4A7C15ull + 1u;
    streams = strtoul(argv[2], NULL, 10);
    for (k = 0; k < streams; k++) {
        size_t n, n_got, n_want, n_intact = 0, i, j;
        uint32_t err;
        int damaged = (k & 1u) != 0u;
        n = damaged ? damaged_stream(stream, intact, &n_intact) : random_stream(stream);
        n_got = stream_through_parser(stream, n, got, MAX_FRAMES * 4, &err);
        n_want = reference(stream, n, want, MAX_FRAMES * 4);
        bytes += n;
        commands += n_got;
        errors += err;
        random_streams += !damaged;
        damaged_streams += damaged;
        if (n_got != n_want) {
            mismatches++;
        } else {
            for (i = 0; i < n_got && i < MAX_FRAMES * 4; i++) {
                if (!same(&got[i], &want[i])) {
                    mismatches++;
                    break;
                }
            }
        }
        /* Every intact frame is one the reference found at its place, unless a damaged frame whose
           CRC matched by chance (a cut frame whose next byte equals its missing CRC byte) overlaps
           it: the protocol itself cannot tell those apart. Both lists are in stream order. */
        for (i = 0, j = 0; i < n_intact; i++) {
            while (j < n_want && want[j].start + IMU_LINK_OVERHEAD + want[j].length <= intact[i].start) {
                j++;
            }
            if (j < n_want && want[j].start == intact[i].start) {
                continue;
            }
            if (j < n_want && want[j].start < intact[i].start + intact[i].size) {
                forged++;
            } else {
                missed++;
            }
        }
    }
    printf("fuzz: %lu streams (%lu random, %lu bit-flipped), %llu bytes, %llu commands, "
           "%llu errors counted, %llu mismatches, %llu intact frames missed, "
           "%llu intact frames overlapped by a damaged frame with a matching CRC\n",
           streams, random_streams, damaged_streams, bytes, commands, errors, mismatches, missed, forged);
    return (mismatches == 0 && missed == 0) ? 0 : 1;
}
