/*
 * A simulated IMU on a pseudo-terminal, speaking the native protocol through imu_link.
 *
 *   cc -std=c99 -O2 -I.. posix_device.c ../imu_link.c -lm -o posix_device
 *   ./posix_device [--rate HZ] [--seed N] [--spin-dps DPS] [--mag] [--serial S] [--model M]
 *                  [--firmware F] [--link PATH]
 *
 * It prints "PORT /dev/pts/N" on its first line, then serves that port as a board serves its
 * UART until SIGINT or SIGTERM: it streams from power-up, answers GET_INFO, SET_RATE,
 * START_STREAM, STOP_STREAM and RESTART, and refuses other commands with ACK status 1. The unit
 * lies flat, z up, with turn-on biases and white noise; --spin-dps turns it about z as a turntable
 * would, --mag adds a magnetometer (IMU_MAG_SAMPLE frames).
 *
 * The main loop is a board's main loop in miniature. What a UART receive interrupt would do,
 * read_port() does: it puts the bytes in an imu_link_ring_t. The loop then takes them out and
 * parses them, answers the commands, and sends the samples due by now on the device clock.
 */
#define _XOPEN_SOURCE 600

#include "../imu_link.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#define G 9.80665
#define PI 3.14159265358979323846
#define MAX_RATE_HZ 8000u
#define TX_CAPACITY 65536u  /* beyond this the host is not reading: new frames are dropped whole */

typedef struct {
    uint16_t power_up_rate_hz;
    uint64_t seed;
    double spin_rad_s;
    int mag;
    const char *serial, *model, *firmware, *link;
} options_t;

typedef struct {
    int master;
    int host;                   /* whether a host has the port open, as the last read said */
    uint8_t tx[TX_CAPACITY];
    size_t tx_len;
    imu_link_ring_t rx;         /* filled as by the receive interrupt */
    imu_link_parser_t parser;
} port_t;

/* What a power cycle resets. */
typedef struct {
    struct timespec power_up;
    uint16_t rate_hz;
    int streaming;
    uint32_t seq;
    uint64_t base_us;           /* samples run on base_us + k / rate_hz from here */
    uint64_t k;
    double acc_bias[3], gyro_bias[3];
    uint64_t rng;
} unit_t;

static volatile sig_atomic_t stop_requested;

static void on_signal(int sig)
{
    (void)sig;
    stop_requested = 1;
}

/* ---- the simulated sensor ------------------------------------------------------------------- */

static double uniform(uint64_t *state)
{
    *state ^= *state >> 12;
    *state ^= *state << 25;
    *state ^= *state >> 27;
    return ((double)((*state * 2685821657736338717ull) >> 11) + 0.5) / 9007199254740992.0;
}

static double gauss(uint64_t *state)
{
    double u = uniform(state), v = uniform(state);
    return sqrt(-2.0 * log(u)) * cos(2.0 * PI * v);
}

static uint64_t now_us(const unit_t *u)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (uint64_t)((int64_t)(t.tv_sec - u->power_up.tv_sec) * 1000000 +
                      (int64_t)(t.tv_nsec - u->power_up.tv_nsec) / 1000);
}

static void power_up(unit_t *u, const options_t *o, unsigned restarts)
{
    int i;
    memset(u, 0, sizeof *u);
    clock_gettime(CLOCK_MONOTONIC, &u->power_up);
    u->rate_hz = o->power_up_rate_hz;
    u->streaming = 1;
    /* New turn-on biases at every power-up, reproducible from the seed. */
    u->rng = (o->seed + restarts) * 0x9E3779B97F4A7C15ull + 1u;
    for (i = 0; i < 3; i++) {
        u->acc_bias[i] = 0.05 * gauss(&u->rng);
        u->gyro_bias[i] = 0.005 * gauss(&u->rng);
    }
}

static void make_sample(unit_t *u, const options_t *o, uint64_t t_us, imu_link_sample_t *s)
{
    static const double field_ut[3] = {22.0, 0.0, -42.0};  /* a mid-latitude field, z up */
    double t = (double)t_us * 1e-6, yaw = o->spin_rad_s * t;
    int i;
    s->seq = u->seq;
    s->t_us = t_us;
    for (i = 0; i < 3; i++) {
        s->acc[i] = (float)((i == 2 ? G : 0.0) + u->acc_bias[i] + 0.02 * gauss(&u->rng));
        s->gyro[i] = (float)((i == 2 ? o->spin_rad_s : 0.0) + u->gyro_bias[i] + 0.002 * gauss(&u->rng));
    }
    s->temp = (float)(25.0 + 3.0 * (1.0 - exp(-t / 120.0)) + 0.01 * gauss(&u->rng));  /* warming up */
    s->has_mag = (uint8_t)o->mag;
    /* The field is fixed in the room: turned by -yaw in the body frame of a spinning unit. */
    s->mag[0] = (float)(cos(yaw) * field_ut[0] + sin(yaw) * field_ut[1] + 0.3 * gauss(&u->rng));
    s->mag[1] = (float)(-sin(yaw) * field_ut[0] + cos(yaw) * field_ut[1] + 0.3 * gauss(&u->rng));
    s->mag[2] = (float)(field_ut[2] + 0.3 * gauss(&u->rng));
}

static uint64_t sample_time(const unit_t *u)
{
    return u->base_us + u->k * 1000000u / u->rate_hz;
}

/* Sample k = 0 at `t_us` from now on, at the unit's rate. */
static void restart_schedule(unit_t *u, uint64_t t_us)
{
    u->base_us = t_us;
    u->k = 0;
}

/* ---- the port ------------------------------------------------------------------------------- */

static void set_raw(int fd)
{
    struct termios t;
    if (tcgetattr(fd, &t) != 0) {
        return;
    }
    t.c_iflag &= (tcflag_t) ~(IGNBRK | BRKINT | PARMRK | ISTRIP | INLCR | IGNCR | ICRNL | IXON);
    t.c_oflag &= (tcflag_t) ~OPOST;
    t.c_lflag &= (tcflag_t) ~(ECHO | ECHONL | ICANON | ISIG | IEXTEN);
    t.c_cflag &= (tcflag_t) ~(CSIZE | PARENB);
    t.c_cflag |= CS8;
    tcsetattr(fd, TCSANOW, &t);
}

/* A raw pty whose slave end is closed: the host opens the path, and until it does reading the
   master fails with EIO, which is how the loop knows nobody listens. */
static int open_port(port_t *port, char *path, size_t cap)
{
    const char *name;
    int slave;
    port->master = posix_openpt(O_RDWR | O_NOCTTY);
    if (port->master < 0 || grantpt(port->master) != 0 || unlockpt(port->master) != 0 ||
        (name = ptsname(port->master)) == NULL || strlen(name) >= cap) {
        return -1;
    }
    strcpy(path, name);
    set_raw(port->master);
    slave = open(path, O_RDWR | O_NOCTTY);
    if (slave >= 0) {
        set_raw(slave);
        close(slave);
    }
    fcntl(port->master, F_SETFL, fcntl(port->master, F_GETFL) | O_NONBLOCK);
    port->host = 0;
    port->tx_len = 0;
    imu_link_ring_init(&port->rx);
    imu_link_parser_init(&port->parser);
    return 0;
}

static void queue_frame(port_t *port, const uint8_t *frame, size_t n)
{
    if (port->host && n > 0u && port->tx_len + n <= TX_CAPACITY) {
        memcpy(port->tx + port->tx_len, frame, n);
        port->tx_len += n;
    }
}

static void lost_host(port_t *port)
{
    port->host = 0;
    port->tx_len = 0;  /* a UART into the void: nothing waits for the next host */
}

static void flush_port(port_t *port)
{
    size_t sent = 0;
    while (sent < port->tx_len) {
        ssize_t n = write(port->master, port->tx + sent, port->tx_len - sent);
        if (n > 0) {
            sent += (size_t)n;
        } else if (n < 0 && errno == EINTR) {
            continue;
        } else if (n < 0 && errno == EAGAIN) {
            break;
        } else {
            lost_host(port);
            return;
        }
    }
    memmove(port->tx, port->tx + sent, port->tx_len - sent);
    port->tx_len -= sent;
}

/* The receive interrupt's work: every byte that arrived goes into the ring. Reads no more than
   the ring has room for, as a UART with flow control would. */
static void read_port(port_t *port)
{
    uint8_t chunk[64];
    for (;;) {
        size_t room = IMU_LINK_RING_SIZE - (uint16_t)(port->rx.head - port->rx.tail), i;
        ssize_t n;
        if (room == 0u) {
            return;
        }
        n = read(port->master, chunk, room < sizeof chunk ? room : sizeof chunk);
        if (n > 0) {
            port->host = 1;
            for (i = 0; i < (size_t)n; i++) {
                imu_link_ring_put(&port->rx, chunk[i]);
            }
        } else if (n < 0 && errno == EINTR) {
            continue;
        } else {
            if (n < 0 && errno == EAGAIN) {
                port->host = 1;
            } else {
                lost_host(port);
            }
            return;
        }
    }
}

/* ---- commands ------------------------------------------------------------------------------- */

static void send_ack(port_t *port, uint8_t id, uint8_t status)
{
    uint8_t frame[16];
    queue_frame(port, frame, imu_link_encode_ack(frame, sizeof frame, id, status));
}

/* Answers one command; returns 1 when it asked for a restart. */
static int handle(port_t *port, unit_t *u, const options_t *o, const imu_link_command_t *cmd)
{
    uint8_t frame[IMU_LINK_MAX_PAYLOAD + IMU_LINK_OVERHEAD];
    switch (cmd->id) {
    case IMU_LINK_GET_INFO:
        queue_frame(port, frame, imu_link_encode_info(frame, sizeof frame, o->serial, o->model, o->firmware,
                                                      u->rate_hz));
        return 0;
    case IMU_LINK_SET_RATE:
        if (cmd->rate_hz == 0u || cmd->rate_hz > MAX_RATE_HZ) {
            send_ack(port, cmd->id, IMU_LINK_ACK_BAD_ARGUMENT);
            return 0;
        }
        restart_schedule(u, u->streaming ? sample_time(u) : now_us(u));
        u->rate_hz = cmd->rate_hz;
        send_ack(port, cmd->id, IMU_LINK_ACK_OK);
        return 0;
    case IMU_LINK_START_STREAM:
        if (!u->streaming) {
            u->streaming = 1;
            restart_schedule(u, now_us(u));
        }
        send_ack(port, cmd->id, IMU_LINK_ACK_OK);
        return 0;
    case IMU_LINK_STOP_STREAM:
        u->streaming = 0;
        send_ack(port, cmd->id, IMU_LINK_ACK_OK);
        return 0;
    case IMU_LINK_RESTART:
        send_ack(port, cmd->id, IMU_LINK_ACK_OK);
        return 1;
    default:
        send_ack(port, cmd->id, IMU_LINK_ACK_UNKNOWN);
        return 0;
    }
}

/* The main loop's work on received bytes; returns 1 when a command asked for a restart. */
static int serve_commands(port_t *port, unit_t *u, const options_t *o)
{
    imu_link_command_t cmd;
    uint8_t byte;
    while (imu_link_ring_get(&port->rx, &byte)) {
        if (!imu_link_parse_byte(&port->parser, byte, &cmd)) {
            continue;
        }
        do {
            if (handle(port, u, o, &cmd)) {
                return 1;
            }
        } while (imu_link_parser_next(&port->parser, &cmd));
    }
    return 0;
}

static void send_due_samples(port_t *port, unit_t *u, const options_t *o)
{
    uint64_t now = now_us(u);
    uint8_t frame[IMU_LINK_MAG_SAMPLE_FRAME_SIZE];
    imu_link_sample_t s;
    while (u->streaming && sample_time(u) <= now) {
        make_sample(u, o, sample_time(u), &s);
        queue_frame(port, frame, imu_link_encode_sample(frame, sizeof frame, &s));
        u->seq++;
        u->k++;
    }
}

/* ---- options and main ----------------------------------------------------------------------- */

static int parse_options(int argc, char **argv, options_t *o)
{
    int i;
    o->power_up_rate_hz = 200;
    o->seed = 1;
    o->spin_rad_s = 0.0;
    o->mag = 0;
    o->serial = "IMULINK-0001";
    o->model = "imu_link POSIX example";
    o->firmware = "imu_link 1.0";
    o->link = NULL;
    for (i = 1; i < argc; i++) {
        const char *arg = argv[i], *value = i + 1 < argc ? argv[i + 1] : NULL;
        char *end = NULL;
        if (strcmp(arg, "--mag") == 0) {
            o->mag = 1;
            continue;
        }
        if (value == NULL) {
            fprintf(stderr, "posix_device: %s needs a value\n", arg);
            return -1;
        }
        i++;
        if (strcmp(arg, "--rate") == 0) {
            unsigned long rate = strtoul(value, &end, 10);
            if (*end != '\0' || rate == 0u || rate > MAX_RATE_HZ) {
                fprintf(stderr, "posix_device: --rate %s: expected 1..%u Hz\n", value, MAX_RATE_HZ);
                return -1;
            }
            o->power_up_rate_hz = (uint16_t)rate;
        } else if (strcmp(arg, "--seed") == 0) {
            o->seed = strtoull(value, &end, 10);
        } else if (strcmp(arg, "--spin-dps") == 0) {
            o->spin_rad_s = strtod(value, &end) * PI / 180.0;
        } else if (strcmp(arg, "--serial") == 0) {
            o->serial = value;
        } else if (strcmp(arg, "--model") == 0) {
            o->model = value;
        } else if (strcmp(arg, "--firmware") == 0) {
            o->firmware = value;
        } else if (strcmp(arg, "--link") == 0) {
            o->link = value;
        } else {
            fprintf(stderr, "posix_device: unknown option %s\n", arg);
            return -1;
        }
        if (end != NULL && (*end != '\0' || end == value)) {
            fprintf(stderr, "posix_device: %s %s: not a number\n", arg, value);
            return -1;
        }
    }
    return 0;
}

int main(int argc, char **argv)
{
    static port_t port;
    static unit_t unit;
    options_t o;
    char path[256];
    struct sigaction sa;
    const struct timespec tick = {0, 1000000};  /* 1 ms: the loop's period */
    unsigned restarts = 0;
    if (parse_options(argc, argv, &o) != 0) {
        return 4;
    }
    if (open_port(&port, path, sizeof path) != 0) {
        perror("posix_device: cannot open a pseudo-terminal");
        return 3;
    }
    if (o.link != NULL) {
        unlink(o.link);
        if (symlink(path, o.link) != 0) {
            perror("posix_device: cannot make the link");
            return 3;
        }
    }
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    printf("PORT %s\n", path);
    fflush(stdout);
    power_up(&unit, &o, restarts);
    while (!stop_requested) {
        read_port(&port);
        if (serve_commands(&port, &unit, &o)) {
            flush_port(&port);  /* the ACK leaves before the unit goes down */
            power_up(&unit, &o, ++restarts);
            imu_link_ring_init(&port.rx);
            imu_link_parser_init(&port.parser);
        }
        send_due_samples(&port, &unit, &o);
        flush_port(&port);
        nanosleep(&tick, NULL);
    }
    if (o.link != NULL) {
        unlink(o.link);
    }
    close(port.master);
    return 0;
}
