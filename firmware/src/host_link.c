/* USART0 with interrupt-driven rings, and the frame decoder and encoders of the bridge protocol.
 *
 * The decoder follows the rules of the host's FrameDecoder (docs/protocol.md, "Decoder and error
 * handling") so both ends resynchronise alike: search A5 5A; refuse another version or an
 * impossible length; wait for the whole frame unless a complete valid frame already starts behind
 * it; check the CRC; on every rejection drop only the first sync byte. Its buffer never holds more
 * than one longest frame (41 bytes). */
#include "host_link.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <string.h>
#include <util/atomic.h>
#include <util/crc16.h>

#include "config.h"

#define SYNC0 0xA5u
#define SYNC1 0x5Au
#define PROTOCOL_VERSION 1u
#define HEADER_LEN 7u
#define CRC_LEN 2u
#define MAX_PAYLOAD_LEN 32u
#define MAX_FRAME_LEN (HEADER_LEN + MAX_PAYLOAD_LEN + CRC_LEN)

#define TYPE_TELEMETRY 0x01u
#define TYPE_COMMAND 0x02u
#define TYPE_VERSION_QUERY 0x03u
#define TYPE_VERSION 0x04u
#define UNKNOWN_TYPE_LEN 0xFFu

/* Ring sizes are powers of two. RX (HOST_RX_RING, 64 bytes) is 5.6 ms of wire time at 115200
 * baud; TX holds four telemetry frames. */
#define TX_RING 128u
/* Bytes decoded per call, so that noise never delays the rest of the loop for long. */
#define BYTES_PER_POLL 16u

volatile uint8_t host_rx_ring[HOST_RX_RING];
volatile uint8_t host_rx_head;
volatile uint8_t host_rx_tail;
static uint8_t tx_ring[TX_RING];
static volatile uint8_t tx_head;
static volatile uint8_t tx_tail;

static uint8_t buf[MAX_FRAME_LEN];
static uint8_t buf_len;
static uint16_t tx_seq;
static struct command pending;
static bool have_pending;

void host_link_init(void)
{
    /* 115200 baud from 16 MHz: U2X with UBRR 16 gives 117647 baud (+2.1 %), within the
     * receivers' tolerance; the usual setting of 16 MHz AVR boards. */
    UCSR0A = _BV(U2X0);
    UBRR0 = 16u;
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

ISR(USART_RX_vect)
{
    host_link_service_rx();
}

/* Enabled only while the ring holds bytes: switched off with the last one, so it never runs
 * empty (avr8js, like some cores, clears UDRE when the interrupt is taken). */
ISR(USART_UDRE_vect)
{
    uint8_t tail = tx_tail;
    UDR0 = tx_ring[tail];
    tail = (uint8_t)((tail + 1u) & (TX_RING - 1u));
    tx_tail = tail;
    if (tail == tx_head) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
    }
}

static void send_frame(uint8_t type, const uint8_t *payload, uint8_t len)
{
    uint8_t head = tx_head;
    uint8_t free_bytes = (uint8_t)((tx_tail - head - 1u) & (TX_RING - 1u));
    uint16_t seq = tx_seq++;
    if (free_bytes < (uint8_t)(len + HEADER_LEN + CRC_LEN)) {
        return;
    }
    uint8_t header[HEADER_LEN] = {
        SYNC0, SYNC1, PROTOCOL_VERSION, type, (uint8_t)seq, (uint8_t)(seq >> 8), len,
    };
    uint16_t crc = 0xFFFFu;
    for (uint8_t i = 0; i < HEADER_LEN; ++i) {
        if (i >= 2u) {
            crc = _crc_xmodem_update(crc, header[i]);
        }
        tx_ring[head] = header[i];
        head = (uint8_t)((head + 1u) & (TX_RING - 1u));
    }
    for (uint8_t i = 0; i < len; ++i) {
        crc = _crc_xmodem_update(crc, payload[i]);
        tx_ring[head] = payload[i];
        head = (uint8_t)((head + 1u) & (TX_RING - 1u));
    }
    tx_ring[head] = (uint8_t)crc;
    head = (uint8_t)((head + 1u) & (TX_RING - 1u));
    tx_ring[head] = (uint8_t)(crc >> 8);
    head = (uint8_t)((head + 1u) & (TX_RING - 1u));
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        tx_head = head;
        UCSR0B |= _BV(UDRIE0);
    }
}

static void put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

void host_link_send_telemetry(const struct telemetry *t)
{
    uint8_t p[17];
    put_u16(p, (uint16_t)t->timestamp_us);
    put_u16(p + 2, (uint16_t)(t->timestamp_us >> 16));
    put_u16(p + 4, t->pulse_us);
    put_u16(p + 6, t->voltage_cv);
    put_u16(p + 8, (uint16_t)t->current_ca);
    put_u16(p + 10, (uint16_t)t->rpm);
    put_u16(p + 12, (uint16_t)((uint32_t)t->rpm >> 16));
    put_u16(p + 14, (uint16_t)t->temperature_cc);
    p[16] = t->status;
    send_frame(TYPE_TELEMETRY, p, sizeof p);
}

static void send_version(void)
{
    static const uint8_t version[3] = {FW_VERSION_MAJOR, FW_VERSION_MINOR, FW_VERSION_PATCH};
    send_frame(TYPE_VERSION, version, sizeof version);
}

/* ---- decoder ---------------------------------------------------------------------------- */

static void drop(uint8_t n)
{
    buf_len = (uint8_t)(buf_len - n);
    memmove(buf, buf + n, buf_len);
}

/* Offset of the first complete sync pair at or after `from`, or -1. */
static int8_t find_sync(uint8_t from)
{
    for (uint8_t i = from; (uint8_t)(i + 1u) < buf_len; ++i) {
        if (buf[i] == SYNC0 && buf[i + 1u] == SYNC1) {
            return (int8_t)i;
        }
    }
    return -1;
}

static uint8_t payload_len_of(uint8_t type)
{
    switch (type) {
    case TYPE_TELEMETRY:
        return 17u;
    case TYPE_COMMAND:
        return 4u;
    case TYPE_VERSION_QUERY:
        return 0u;
    case TYPE_VERSION:
        return 3u;
    default:
        return UNKNOWN_TYPE_LEN;
    }
}

static bool header_ok(uint8_t pos)
{
    if (buf[pos + 2u] != PROTOCOL_VERSION) {
        return false;
    }
    uint8_t len = buf[pos + 6u];
    uint8_t want = payload_len_of(buf[pos + 3u]);
    return len <= MAX_PAYLOAD_LEN && (want == UNKNOWN_TYPE_LEN || want == len);
}

static bool crc_ok(uint8_t pos, uint8_t end)
{
    uint16_t crc = 0xFFFFu;
    for (uint8_t i = (uint8_t)(pos + 2u); i < (uint8_t)(end - CRC_LEN); ++i) {
        crc = _crc_xmodem_update(crc, buf[i]);
    }
    return (uint8_t)crc == buf[end - 2u] && (uint8_t)(crc >> 8) == buf[end - 1u];
}

/* Offset of a complete, valid frame behind the candidate at 0, or -1. */
static int8_t later_frame(void)
{
    int8_t pos = find_sync(2u);
    while (pos >= 0 && (uint8_t)pos + HEADER_LEN <= buf_len) {
        uint16_t end = (uint16_t)pos + HEADER_LEN + buf[pos + 6] + CRC_LEN;
        if (header_ok((uint8_t)pos) && end <= buf_len && crc_ok((uint8_t)pos, (uint8_t)end)) {
            return pos;
        }
        pos = find_sync((uint8_t)(pos + 1));
    }
    return -1;
}

static void handle(uint8_t type, const uint8_t *payload)
{
    if (type == TYPE_COMMAND) {
        pending.pulse_us = (uint16_t)(payload[0] | ((uint16_t)payload[1] << 8));
        pending.timeout_ms = (uint16_t)(payload[2] | ((uint16_t)payload[3] << 8));
        have_pending = true;
    } else if (type == TYPE_VERSION_QUERY) {
        send_version();
    }
}

static void drain(void)
{
    while (buf_len > 0u) {
        int8_t pos = find_sync(0u);
        if (pos < 0) {
            /* A trailing first sync byte may be completed by the next byte. */
            drop((uint8_t)(buf_len - (buf[buf_len - 1u] == SYNC0)));
            return;
        }
        drop((uint8_t)pos);
        if (buf_len < HEADER_LEN) {
            return;
        }
        if (!header_ok(0u)) {
            drop(1u);
            continue;
        }
        uint8_t end = (uint8_t)(HEADER_LEN + buf[6] + CRC_LEN);
        if (buf_len < end) {
            /* A whole valid frame behind this sync means the candidate was cut short. */
            int8_t later = later_frame();
            if (later < 0) {
                return;
            }
            drop((uint8_t)later);
            continue;
        }
        if (!crc_ok(0u, end)) {
            drop(1u);
            continue;
        }
        handle(buf[3], buf + HEADER_LEN);
        drop(end);
    }
}

bool host_link_poll(struct command *out)
{
    for (uint8_t n = 0; n < BYTES_PER_POLL; ++n) {
        uint8_t tail = host_rx_tail;
        if (tail == host_rx_head) {
            break;
        }
        /* After drain() the buffer holds less than a longest frame, so one more byte fits. */
        buf[buf_len++] = host_rx_ring[tail];
        host_rx_tail = (uint8_t)((tail + 1u) & (HOST_RX_RING - 1u));
        drain();
    }
    if (!have_pending) {
        return false;
    }
    *out = pending;
    have_pending = false;
    return true;
}
