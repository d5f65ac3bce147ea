/*
 * A tiny Modbus TCP server on libmodbus, standing in for a third-party
 * controller in tests/drivers/test_modbus_interop.py.
 *
 * Listens on 127.0.0.1, port from argv[1] (0 = any free port), prints
 * "LISTENING <port>" once ready, serves ONE client connection, and when
 * that client disconnects prints every holding register as "HR <addr> <value>"
 * and exits 0. alarm(30) bounds its life if a test goes wrong.
 *
 * Register map (protocol addresses, 0-based):
 *   input   0..1  float32 21.5      high word first ("big", libmodbus's ABCD)
 *   input   2..3  float32 -123.25   low word first ("little", libmodbus's CDAB)
 *   input   4     int16   -1234
 *   input   5     int16   0x7FFF    (an open-Pt100 sentinel)
 *   input   6..7  int32   -123456   high word first
 *   holding 0..15 zeros, writable
 *   anything else: exception 2 (illegal data address), libmodbus's own answer
 */
#include <arpa/inet.h>
#include <errno.h>
#include <modbus.h>
#include <netinet/in.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

/* The words are set by hand: libmodbus 3.1.6's modbus_set_float_abcd/_cdab
 * swap the bytes inside each register on little-endian hosts (seen on
 * Debian 12's 3.1.6: 21.5f came out as 0xAC41 0x0000). */
static uint32_t float_bits(float value)
{
    uint32_t bits;
    memcpy(&bits, &value, sizeof bits);
    return bits;
}

static void put32(uint16_t *dst, uint32_t value, int high_word_first)
{
    uint16_t high = (uint16_t)(value >> 16), low = (uint16_t)(value & 0xFFFF);
    dst[0] = high_word_first ? high : low;
    dst[1] = high_word_first ? low : high;
}

int main(int argc, char **argv)
{
    int port = argc > 1 ? atoi(argv[1]) : 0;
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", port);
    if (ctx == NULL) {
        fprintf(stderr, "modbus_new_tcp: %s\n", modbus_strerror(errno));
        return 2;
    }
    modbus_mapping_t *map = modbus_mapping_new_start_address(0, 0, 0, 0, 0, 16, 0, 8);
    if (map == NULL) {
        fprintf(stderr, "modbus_mapping_new: %s\n", modbus_strerror(errno));
        return 2;
    }
    uint16_t *ir = map->tab_input_registers;
    put32(&ir[0], float_bits(21.5f), 1);
    put32(&ir[2], float_bits(-123.25f), 0);
    ir[4] = (uint16_t)(int16_t)-1234;
    ir[5] = 0x7FFF;
    put32(&ir[6], (uint32_t)(int32_t)-123456, 1);

    int listener = modbus_tcp_listen(ctx, 1);
    if (listener < 0) {
        fprintf(stderr, "modbus_tcp_listen: %s\n", modbus_strerror(errno));
        return 2;
    }
    struct sockaddr_in bound;
    socklen_t len = sizeof bound;
    if (getsockname(listener, (struct sockaddr *)&bound, &len) != 0) {
        perror("getsockname");
        return 2;
    }
    printf("LISTENING %d\n", ntohs(bound.sin_port));
    fflush(stdout);
    alarm(30);

    if (modbus_tcp_accept(ctx, &listener) < 0) {
        fprintf(stderr, "modbus_tcp_accept: %s\n", modbus_strerror(errno));
        return 2;
    }
    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
    for (;;) {
        int rc = modbus_receive(ctx, query);
        if (rc > 0) {
            modbus_reply(ctx, query, rc, map);
        } else if (rc == -1) {
            break; /* client closed the connection */
        }
    }
    for (int i = 0; i < map->nb_registers; i++) {
        printf("HR %d %u\n", i, map->tab_registers[i]);
    }
    fflush(stdout);
    close(listener);
    modbus_mapping_free(map);
    modbus_close(ctx);
    modbus_free(ctx);
    return 0;
}
