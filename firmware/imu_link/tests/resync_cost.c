/*
 * The parser's worst byte, measured: the bytes its CRCs cover in one imu_link_parse_byte() call.
 *
 * The worst stream fills the parser's buffer with false starts 5 bytes apart (a sync, an id and
 * a length: the closest two starts can be, since a sync inside another start's length bytes makes
 * that length absurd), each claiming a frame that ends at the buffer's last byte. That byte
 * completes the first one; its CRC fails, the parser searches on from the byte after its sync and
 * finds the next false start complete, and so on: every one costs a CRC over the rest of the buffer.
 * Compiled with IMU_LINK_COUNT_CRC defined to count, by including the library's source.
 *
 * Prints: "worst_byte_crc_bytes N false_starts K clean_byte_crc_bytes M".
 */
#include <stdio.h>

static unsigned long crc_bytes;
#define IMU_LINK_COUNT_CRC(bytes) (crc_bytes += (unsigned long)(bytes))
#include "../imu_link.c"

#define CAPACITY (IMU_LINK_RX_MAX_PAYLOAD + IMU_LINK_OVERHEAD)

static imu_link_parser_t parser;
static uint8_t stream[CAPACITY];

int main(void)
{
    imu_link_command_t cmd;
    unsigned long worst = 0, clean = 0;
    size_t at, starts = 0, i;
    uint8_t frame[IMU_LINK_OVERHEAD + 2u];
    uint8_t rate[2] = {100u, 0u};
    size_t n;

    memset(stream, 0x00, sizeof stream);
    for (at = 0; at + IMU_LINK_OVERHEAD <= CAPACITY; at += 5u) {
        size_t length = CAPACITY - at - IMU_LINK_OVERHEAD;  /* the claimed frame ends at the last byte */
        stream[at] = 0xA5u;
        stream[at + 1u] = 0x5Au;
        stream[at + 2u] = (uint8_t)(0x20u + (starts & 0x3Fu));  /* an id no command has */
        stream[at + 3u] = (uint8_t)(length & 0xFFu);
        stream[at + 4u] = (uint8_t)(length >> 8);
        starts++;
    }
    /* A CRC that happens to match would end the cascade early: none may (checked, not assumed). */
    for (at = 0; at + IMU_LINK_OVERHEAD <= CAPACITY; at += 5u) {
        size_t end = CAPACITY;
        if (imu_link_crc16(stream + at + 2u, end - at - 4u) ==
            (uint16_t)(stream[end - 2u] | (stream[end - 1u] << 8))) {
            printf("a false start's CRC matches at %lu\n", (unsigned long)at);
            return 1;
        }
    }
    imu_link_parser_init(&parser);
    for (i = 0; i < CAPACITY; i++) {
        crc_bytes = 0;
        while (imu_link_parse_byte(&parser, stream[i], &cmd)) {
            return 2;  /* no false start may pass for a command */
        }
        if (crc_bytes > worst) {
            worst = crc_bytes;
        }
    }
    /* A clean stream of the longest command the protocol has (SET_RATE): what one byte costs there. */
    n = imu_link_encode_frame(frame, sizeof frame, IMU_LINK_SET_RATE, rate, sizeof rate);
    imu_link_parser_init(&parser);
    for (i = 0; i < 100u * n; i++) {
        crc_bytes = 0;
        if (imu_link_parse_byte(&parser, frame[i % n], &cmd) && cmd.rate_hz != 100u) {
            return 3;
        }
        if (crc_bytes > clean) {
            clean = crc_bytes;
        }
    }
    printf("worst_byte_crc_bytes %lu false_starts %lu clean_byte_crc_bytes %lu\n", worst,
           (unsigned long)starts, clean);
    return 0;
}
