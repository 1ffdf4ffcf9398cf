/* Independent test harness for the exported C (tests/test_export_c.py drives it).
 *
 *   harness load BLOB...          prints "<rc> <untouched>" per blob: imu_calib_load's result and
 *                                 whether *out kept its prior bytes
 *   harness apply BLOB IN OUT     IN: float32 rows (temp, dtemp, acc xyz, gyro xyz, mag xyz); OUT:
 *                                 float32 rows (acc xyz, gyro xyz, mag xyz) from the blob
 *                                 (imu_calib_apply, imu_calib_apply_mag); prints "unit_equal <0|1>"
 *                                 (the header's linked-in parameters equal the blob's),
 *                                 "unit_same_output <0|1>" and "flags <n>"
 *   harness dtemp BLOB IN OUT     IN: float32 rows (dt, temp); OUT: float32 dT per row
 *   harness stream BLOB IN OUT    IN: float32 rows (dt, temp, acc xyz, gyro xyz): dT from the
 *                                 firmware filter, then apply, as a firmware loop would; OUT as apply
 *   harness strings               prints the unit's string macros as hex bytes, one per line
 *
 * Written in the common subset of C99 and C++ so the same file checks both builds.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "imu_calib.h"

static unsigned char *read_all(const char *path, size_t *len)
{
    FILE *f = fopen(path, "rb");
    unsigned char *buf;
    long size;
    if (f == NULL) {
        fprintf(stderr, "cannot open %s\n", path);
        exit(2);
    }
    fseek(f, 0, SEEK_END);
    size = ftell(f);
    fseek(f, 0, SEEK_SET);
    buf = (unsigned char *)malloc((size_t)size + 1u);
    if (buf == NULL || fread(buf, 1, (size_t)size, f) != (size_t)size) {
        fprintf(stderr, "cannot read %s\n", path);
        exit(2);
    }
    fclose(f);
    *len = (size_t)size;
    return buf;
}

static void write_all(const char *path, const float *data, size_t n)
{
    FILE *f = fopen(path, "wb");
    if (f == NULL || fwrite(data, sizeof(float), n, f) != n) {
        fprintf(stderr, "cannot write %s\n", path);
        exit(2);
    }
    fclose(f);
}

static int same_thermal(const imu_calib_thermal_t *a, const imu_calib_thermal_t *b)
{
    return a->n_segments == b->n_segments && memcmp(&a->dt_min, &b->dt_min, sizeof a->dt_min) == 0
        && memcmp(&a->dt_max, &b->dt_max, sizeof a->dt_max) == 0
        && memcmp(a->segments, b->segments, sizeof a->segments) == 0;
}

static int same_params(const imu_calib_t *a, const imu_calib_t *b)
{
    return a->format_version == b->format_version && a->schema_version == b->schema_version
        && a->flags == b->flags && a->created_utc == b->created_utc && a->exported_utc == b->exported_utc
        && memcmp(a->serial, b->serial, sizeof a->serial) == 0
        && memcmp(a->station_id, b->station_id, sizeof a->station_id) == 0
        && memcmp(&a->reference_temp, &b->reference_temp, sizeof a->reference_temp) == 0
        && memcmp(&a->dtemp_tau_s, &b->dtemp_tau_s, sizeof a->dtemp_tau_s) == 0
        && memcmp(&a->accel, &b->accel, sizeof a->accel) == 0
        && memcmp(&a->gyro, &b->gyro, sizeof a->gyro) == 0
        && same_thermal(&a->accel_thermal, &b->accel_thermal)
        && same_thermal(&a->gyro_thermal, &b->gyro_thermal)
        && memcmp(&a->mag, &b->mag, sizeof a->mag) == 0
        && memcmp(a->g_sensitivity, b->g_sensitivity, sizeof a->g_sensitivity) == 0
        && memcmp(&a->accel_intrinsics, &b->accel_intrinsics, sizeof a->accel_intrinsics) == 0
        && memcmp(&a->gyro_intrinsics, &b->gyro_intrinsics, sizeof a->gyro_intrinsics) == 0;
}

static void load_or_die(const char *path, imu_calib_t *p)
{
    size_t len;
    unsigned char *blob = read_all(path, &len);
    int rc = imu_calib_load(p, blob, len);
    free(blob);
    if (rc != IMU_CALIB_OK) {
        fprintf(stderr, "load %s: %d %s\n", path, rc, imu_calib_strerror(rc));
        exit(3);
    }
}

static void print_hex(const char *name, const char *s)
{
    size_t i, n = strlen(s);
    printf("%s", name);
    for (i = 0; i < n; ++i) {
        printf(" %02x", (unsigned)(unsigned char)s[i]);
    }
    printf("\n");
}

int main(int argc, char **argv)
{
    static imu_calib_t p, before;
    size_t len, n, i;

    if (argc >= 3 && strcmp(argv[1], "load") == 0) {
        int k;
        for (k = 2; k < argc; ++k) {
            unsigned char *blob = read_all(argv[k], &len);
            int rc;
            memset(&p, 0xA5, sizeof p);
            memcpy(&before, &p, sizeof p);
            rc = imu_calib_load(&p, blob, len);
            printf("%d %d\n", rc, memcmp(&p, &before, sizeof p) == 0);
            free(blob);
        }
        return 0;
    }
    if (argc == 5 && strcmp(argv[1], "apply") == 0) {
        float *in, *out, *out_unit;
        int same = 1;
        load_or_die(argv[2], &p);
        printf("unit_equal %d\n", same_params(&p, &imu_calib_unit));
        printf("flags %u\n", (unsigned)p.flags);
        in = (float *)(void *)read_all(argv[3], &len);
        n = len / (11u * sizeof(float));
        out = (float *)malloc(9u * n * sizeof(float) + 1u);
        out_unit = (float *)malloc(9u * n * sizeof(float) + 1u);
        for (i = 0; i < n; ++i) {
            const float *row = in + 11u * i;
            float *o = out + 9u * i, *u = out_unit + 9u * i;
            imu_calib_apply(&p, row[0], row[1], row + 2, row + 5, o, o + 3);
            imu_calib_apply_mag(&p, row + 8, o + 6);
            imu_calib_apply(&imu_calib_unit, row[0], row[1], row + 2, row + 5, u, u + 3);
            imu_calib_apply_mag(&imu_calib_unit, row + 8, u + 6);
        }
        for (i = 0; i < 9u * n; ++i) {
            if (memcmp(&out[i], &out_unit[i], sizeof(float)) != 0) {
                same = 0;
            }
        }
        printf("unit_same_output %d\n", same);
        write_all(argv[4], out, 9u * n);
        return 0;
    }
    if (argc == 5 && strcmp(argv[1], "dtemp") == 0) {
        float *in, *out;
        imu_calib_dtemp_t state;
        load_or_die(argv[2], &p);
        in = (float *)(void *)read_all(argv[3], &len);
        n = len / (2u * sizeof(float));
        out = (float *)malloc(n * sizeof(float) + 1u);
        imu_calib_dtemp_init(&state);
        for (i = 0; i < n; ++i) {
            out[i] = imu_calib_dtemp_update(&state, &p, in[2u * i], in[2u * i + 1u]);
        }
        write_all(argv[4], out, n);
        return 0;
    }
    if (argc == 5 && strcmp(argv[1], "stream") == 0) {
        float *in, *out;
        imu_calib_dtemp_t state;
        load_or_die(argv[2], &p);
        in = (float *)(void *)read_all(argv[3], &len);
        n = len / (8u * sizeof(float));
        out = (float *)malloc(6u * n * sizeof(float) + 1u);
        imu_calib_dtemp_init(&state);
        for (i = 0; i < n; ++i) {
            const float *row = in + 8u * i;
            float dtemp = imu_calib_dtemp_update(&state, &p, row[0], row[1]);
            imu_calib_apply(&p, row[1], dtemp, row + 2, row + 5, out + 6u * i, out + 6u * i + 3u);
        }
        write_all(argv[4], out, 6u * n);
        return 0;
    }
    if (argc == 2 && strcmp(argv[1], "strings") == 0) {
        print_hex("serial", IMU_CALIB_UNIT_SERIAL);
        print_hex("model", IMU_CALIB_UNIT_MODEL);
        print_hex("firmware", IMU_CALIB_UNIT_FIRMWARE);
        print_hex("station", IMU_CALIB_STATION_ID);
        print_hex("unit_serial", imu_calib_unit.serial);
        print_hex("unit_station", imu_calib_unit.station_id);
        return 0;
    }
    fprintf(stderr, "usage: harness load BLOB... | apply|dtemp|stream BLOB IN OUT | strings\n");
    return 2;
}
