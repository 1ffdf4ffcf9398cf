/*
 * imu_link: the device side of the imu-station native protocol, version 1.
 *
 * Drop imu_link.h and imu_link.c into a firmware and the board speaks the protocol of
 * shared/specs/native-protocol.md. Plain C99: no allocation, no global state, nothing of the
 * C library beyond <stdint.h>, <stddef.h> and <string.h>, no floating-point formatting.
 *
 * Interrupt safety: every function works only on the objects it is given, so the UART receive
 * interrupt may call imu_link_parse_byte() on a parser that nothing else touches. Most bytes cost
 * a few comparisons, but the byte that completes a frame checks its CRC, and resynchronising
 * after a damaged frame searches again the bytes that frame claimed, checking the CRC of every
 * false start among them whose claimed frame is complete. The worst case, measured by
 * tests/resync_cost.c: 205 overlapping false starts, 5 bytes apart and each claiming a frame that
 * ends at the same byte, make that one byte cost CRCs over 105985 bytes with the default
 * IMU_LINK_RX_MAX_PAYLOAD of 1024 (about 103 times the CRC of the longest frame; in general about
 * (IMU_LINK_RX_MAX_PAYLOAD + 7)^2 / 10 bytes), where a byte of a clean stream costs at most one
 * frame's CRC. A firmware that cannot spend that in its interrupt puts the bytes in an
 * imu_link_ring_t from the interrupt (imu_link_ring_put) and parses them in its main loop
 * (imu_link_ring_get): the one-producer, one-consumer queue below.
 *
 * 8-bit parts: the ring's head and tail are uint16_t by default, which an 8-bit CPU (AVR, 8051,
 * PIC) reads in two instructions; an interrupt between them tears the value, and the main loop may
 * take bytes that were never put. There, compile with -DIMU_LINK_RING_INDEX=uint8_t (and an
 * IMU_LINK_RING_SIZE of at most 128): each index is then one byte, read and written whole. The
 * `dropped` counter stays a uint32_t: read it with the receive interrupt disabled.
 */
#ifndef IMU_LINK_H
#define IMU_LINK_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Message ids of the native protocol. */
#define IMU_LINK_IMU_SAMPLE 0x01u
#define IMU_LINK_DEVICE_INFO 0x02u
#define IMU_LINK_ACK 0x03u
#define IMU_LINK_IMU_MAG_SAMPLE 0x04u
#define IMU_LINK_GET_INFO 0x10u
#define IMU_LINK_SET_RATE 0x11u
#define IMU_LINK_START_STREAM 0x12u
#define IMU_LINK_STOP_STREAM 0x13u
#define IMU_LINK_RESTART 0x14u

/* ACK statuses. */
#define IMU_LINK_ACK_OK 0u
#define IMU_LINK_ACK_UNKNOWN 1u
#define IMU_LINK_ACK_BAD_ARGUMENT 2u
#define IMU_LINK_ACK_BUSY 3u

/* Frame layout: sync A5 5A, id, u16 length, payload, u16 CRC. */
#define IMU_LINK_OVERHEAD 7u
#define IMU_LINK_MAX_PAYLOAD 1024u
#define IMU_LINK_SAMPLE_FRAME_SIZE 47u      /* IMU_SAMPLE: 40-byte payload */
#define IMU_LINK_MAG_SAMPLE_FRAME_SIZE 59u  /* IMU_MAG_SAMPLE: 52-byte payload */

/* The longest host frame payload the parser accepts; longer ones count as errors. The protocol
   allows 1024; a board short of RAM may define a smaller value (at least 2, for SET_RATE) when it
   compiles imu_link.c, at the cost of refusing longer commands the protocol may add. */
#ifndef IMU_LINK_RX_MAX_PAYLOAD
#define IMU_LINK_RX_MAX_PAYLOAD IMU_LINK_MAX_PAYLOAD
#endif

/* Size of imu_link_ring_t's queue, a power of two no larger than 32768 (128 with 8-bit indices). */
#ifndef IMU_LINK_RING_SIZE
#define IMU_LINK_RING_SIZE 256u
#endif

/* The ring's index type: uint16_t, or uint8_t where a 16-bit read is not atomic (8-bit parts, see above). */
#ifndef IMU_LINK_RING_INDEX
#define IMU_LINK_RING_INDEX uint16_t
#endif
typedef IMU_LINK_RING_INDEX imu_link_ring_index_t;

typedef struct {
    uint32_t seq;
    uint64_t t_us;
    float acc[3], gyro[3], temp;
    float mag[3];
    uint8_t has_mag;            /* 1: IMU_MAG_SAMPLE, 0: IMU_SAMPLE */
} imu_link_sample_t;

typedef struct {
    uint8_t id;                 /* 0x10 GET_INFO, 0x11 SET_RATE, 0x12 START, 0x13 STOP, 0x14 RESTART, or another id */
    uint16_t length;
    uint8_t payload[64];        /* the first 64 bytes of the payload */
    uint16_t rate_hz;           /* SET_RATE's argument, decoded; 0 unless SET_RATE carries exactly 2 bytes */
} imu_link_command_t;

/* Opaque to the user: parser state, no pointers into user memory. It keeps the bytes of the
   frame being received, so that a damaged frame's bytes can be searched again for the next one. */
typedef struct {
    uint8_t buf[IMU_LINK_RX_MAX_PAYLOAD + IMU_LINK_OVERHEAD];
    uint16_t head, tail;        /* the bytes not yet resolved are buf[head .. tail) */
    uint32_t errors;
    uint8_t in_garbage;         /* 1 while skipping bytes already counted as one error */
} imu_link_parser_t;

/* One-producer, one-consumer byte queue: an interrupt puts, the main loop gets. */
typedef struct {
    volatile imu_link_ring_index_t head;     /* written only by imu_link_ring_put */
    volatile imu_link_ring_index_t tail;     /* written only by imu_link_ring_get */
    volatile uint32_t dropped;  /* bytes put while the queue was full */
    volatile uint8_t data[IMU_LINK_RING_SIZE];
} imu_link_ring_t;

/* Each encoder writes one whole frame into buf and returns its length, or 0 when cap is too small. */
size_t imu_link_encode_sample(uint8_t *buf, size_t cap, const imu_link_sample_t *s);
size_t imu_link_encode_info(uint8_t *buf, size_t cap, const char *serial, const char *model,
                            const char *firmware, uint16_t rate_hz);   /* JSON-escapes the strings */
size_t imu_link_encode_ack(uint8_t *buf, size_t cap, uint8_t command_id, uint8_t status);

/* Any frame: for messages the three encoders above do not cover. Returns 0 when cap is too small
   or len exceeds IMU_LINK_MAX_PAYLOAD. */
size_t imu_link_encode_frame(uint8_t *buf, size_t cap, uint8_t id, const uint8_t *payload, size_t len);

/* Host commands arrive a byte at a time. Returns 1 when `byte` completed a valid frame (CRC
   checked), filling *cmd; 0 otherwise. Garbage, bad CRCs and absurd lengths are skipped and
   counted, and never lose a good command that follows. */
void imu_link_parser_init(imu_link_parser_t *p);
int imu_link_parse_byte(imu_link_parser_t *p, uint8_t byte, imu_link_command_t *cmd);
uint32_t imu_link_parser_errors(const imu_link_parser_t *p);

/* A further command already complete in the parser, without a new byte: 1 and *cmd filled, or 0.
   Only needed after a damaged frame hid several short commands that one byte then completed at
   once; a loop `while (imu_link_parser_next(p, &cmd))` after each imu_link_parse_byte() that
   returned 1 hands them all over. */
int imu_link_parser_next(imu_link_parser_t *p, imu_link_command_t *cmd);

uint16_t imu_link_crc16(const uint8_t *data, size_t len);   /* CRC-16/CCITT-FALSE */

void imu_link_ring_init(imu_link_ring_t *r);
/* From the interrupt: 1 if queued, 0 if the queue was full (the byte is dropped and counted). */
int imu_link_ring_put(imu_link_ring_t *r, uint8_t byte);
/* From the main loop: 1 and *byte filled, or 0 when the queue is empty. */
int imu_link_ring_get(imu_link_ring_t *r, uint8_t *byte);

#ifdef __cplusplus
}
#endif

#endif /* IMU_LINK_H */
