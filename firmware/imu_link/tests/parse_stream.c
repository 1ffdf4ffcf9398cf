/*
 * Parses standard input a byte at a time with imu_link and prints one line per command:
 * "ID LENGTH HEX" (hex of the first 64 payload bytes), then "errors N". The station's tests feed
 * the same bytes to the station's own decoder and compare.
 */
#include "../imu_link.h"

#include <stdio.h>

static void print_command(const imu_link_command_t *cmd)
{
    unsigned i, kept = cmd->length < 64u ? cmd->length : 64u;
    printf("%u %u ", (unsigned)cmd->id, (unsigned)cmd->length);
    for (i = 0; i < kept; i++) {
        printf("%02x", (unsigned)cmd->payload[i]);
    }
    printf("\n");
}

int main(void)
{
    static imu_link_parser_t parser;
    imu_link_command_t cmd;
    int c;
    imu_link_parser_init(&parser);
    while ((c = getchar()) != EOF) {
        if (!imu_link_parse_byte(&parser, (uint8_t)c, &cmd)) {
            continue;
        }
        do {
            print_command(&cmd);
        } while (imu_link_parser_next(&parser, &cmd));
    }
    printf("errors %lu\n", (unsigned long)imu_link_parser_errors(&parser));
    return 0;
}
