/* Graupner HoTT ESC telemetry: the bridge acts as the HoTT receiver and polls the ESC's sensor.
 *
 * One wire, half duplex, 19200 baud 8N1, idle high (not inverted). The bridge drives the wire to
 * send the binary-mode request 0x80 0x8C (ESC module), then releases it (input, pull-up) and
 * receives the 45-byte reply: 0x7C, 0x8C, warning, 0xC0, ..., 0x7D, checksum = sum of the 44
 * bytes before it, mod 256. The layout, and where it comes from, is in firmware/README.md.
 *
 * Bits are timed by Timer2 in CTC mode at clk/8 (0.5 µs ticks): 104 ticks per bit (52 µs, 19231
 * baud, +0.16 %). Receiving, a falling edge on INT0 marks a start bit and the timer samples each
 * bit in its middle, so the main loop never waits on the wire. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>

#include "esc.h"
#include "wake.h"

#define BIT_TICKS 104u
#define FRAME_LEN 45u
#define REQUEST_BINARY 0x80u
#define ESC_MODULE_ID 0x8Cu
#define ESC_TEXT_ID 0xC0u
#define START_BYTE 0x7Cu
#define END_BYTE 0x7Du
/* A sensor answers after a few ms and spaces its bytes by about 1.2 ms (about 60 ms for a frame,
 * see README): wait this long for the whole reply, then this long before the next request. */
#define REPLY_TIMEOUT_US 150000UL
#define POLL_GAP_US 5000UL

enum phase { PHASE_IDLE, PHASE_TX, PHASE_RX };

static volatile uint8_t phase;
static volatile uint8_t bit_index;
static volatile uint8_t shift;
static volatile uint8_t tx_index;
static volatile uint8_t rx_count;
static volatile uint8_t framing_error;
static volatile uint8_t rx_buf[FRAME_LEN];
static const uint8_t request[2] = {REQUEST_BINARY, ESC_MODULE_ID};
static uint32_t poll_start_us;
static uint32_t idle_since_us;

static void wire_level(uint8_t high)
{
    if (high) {
        PORTD |= _BV(PD2);
    } else {
        PORTD &= (uint8_t)~_BV(PD2);
    }
}

static void timer2_start(uint8_t ticks)
{
    TCCR2B = 0;
    TCNT2 = 0;
    OCR2A = (uint8_t)(ticks - 1u);
    TIFR2 = _BV(OCF2A);
    TIMSK2 = _BV(OCIE2A);
    TCCR2B = _BV(CS21);
}

static void timer2_stop(void)
{
    TCCR2B = 0;
    TIMSK2 = 0;
}

static void listen_for_start_bit(void)
{
    EIFR = _BV(INTF0);
    EIMSK |= _BV(INT0);
}

void esc_init(void)
{
    DDRD &= (uint8_t)~_BV(PD2);
    PORTD |= _BV(PD2);
    TCCR2A = _BV(WGM21);
    EICRA = (uint8_t)((EICRA & (uint8_t)~(_BV(ISC01) | _BV(ISC00))) | _BV(ISC01));
    phase = PHASE_IDLE;
}

ISR(INT0_vect)
{
    EIMSK &= (uint8_t)~_BV(INT0);
    shift = 0;
    bit_index = 0;
    /* First sample in the middle of data bit 0, one and a half bits after the start edge. */
    timer2_start((uint8_t)(BIT_TICKS + BIT_TICKS / 2u));
}

static void transmit_tick(void)
{
    uint8_t bit = (uint8_t)(bit_index + 1u);
    if (bit <= 8u) {
        wire_level((uint8_t)((shift >> (bit - 1u)) & 1u));
    } else if (bit == 9u) {
        wire_level(1);
    } else if ((uint8_t)(tx_index + 1u) < sizeof request) {
        tx_index = (uint8_t)(tx_index + 1u);
        shift = request[tx_index];
        bit = 0;
        wire_level(0);
    } else {
        /* Request sent: release the wire to the ESC. */
        timer2_stop();
        DDRD &= (uint8_t)~_BV(PD2);
        phase = PHASE_RX;
        listen_for_start_bit();
        return;
    }
    bit_index = bit;
}

static void receive_tick(void)
{
    uint8_t bit = bit_index;
    uint8_t high = (uint8_t)(PIND & _BV(PD2));
    if (bit < 8u) {
        if (high) {
            shift = (uint8_t)(shift | (uint8_t)(1u << bit));
        }
        if (bit == 0u) {
            OCR2A = BIT_TICKS - 1u;
        }
        bit_index = (uint8_t)(bit + 1u);
        return;
    }
    /* Stop bit. */
    timer2_stop();
    if (!high) {
        framing_error = 1;
    }
    if (rx_count < FRAME_LEN) {
        rx_buf[rx_count] = shift;
        rx_count = (uint8_t)(rx_count + 1u);
        if (rx_count == FRAME_LEN) {
            wake_main_loop();
        }
    }
    listen_for_start_bit();
}

ISR(TIMER2_COMPA_vect)
{
    if (phase == PHASE_TX) {
        transmit_tick();
    } else {
        receive_tick();
    }
}

static void start_request(uint32_t now_us)
{
    rx_count = 0;
    framing_error = 0;
    tx_index = 0;
    bit_index = 0;
    shift = request[0];
    phase = PHASE_TX;
    poll_start_us = now_us;
    /* Start bit now; the timer times the rest. */
    wire_level(0);
    DDRD |= _BV(PD2);
    timer2_start(BIT_TICKS);
}

static void end_exchange(uint32_t now_us)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        EIMSK &= (uint8_t)~_BV(INT0);
        timer2_stop();
        phase = PHASE_IDLE;
    }
    wire_level(1);
    idle_since_us = now_us;
}

static uint16_t le16(uint8_t at)
{
    return (uint16_t)(rx_buf[at] | ((uint16_t)rx_buf[at + 1u] << 8));
}

static enum esc_result parse(struct esc_reading *out)
{
    if (framing_error || rx_buf[0] != START_BYTE || rx_buf[1] != ESC_MODULE_ID
        || rx_buf[3] != ESC_TEXT_ID || rx_buf[43] != END_BYTE) {
        return ESC_BAD;
    }
    uint8_t sum = 0;
    for (uint8_t i = 0; i < FRAME_LEN - 1u; ++i) {
        sum = (uint8_t)(sum + rx_buf[i]);
    }
    if (sum != rx_buf[FRAME_LEN - 1u]) {
        return ESC_BAD;
    }
    uint16_t voltage_dv = le16(6);
    uint16_t current_da = le16(14);
    uint16_t rpm_10 = le16(18);
    /* Compare in the frame's units first: the conversions below must not overflow. */
    if (voltage_dv > VOLTAGE_MAX_CV / 10u || current_da > CURRENT_MAX_CA / 10u
        || rpm_10 > RPM_MAX / 10u) {
        return ESC_BAD;
    }
    struct esc_reading r = {
        .voltage_cv = (uint16_t)(voltage_dv * 10u),
        .current_ca = (uint16_t)(current_da * 10u),
        .rpm = (uint16_t)(rpm_10 * 10u),
        .temperature_cc = (int16_t)(((int16_t)rx_buf[12] - 20) * 100),
    };
    if (!esc_reading_plausible(&r)) {
        return ESC_BAD;
    }
    *out = r;
    return ESC_NEW;
}

enum esc_result esc_poll(uint32_t now_us, struct esc_reading *out)
{
    uint8_t ph = phase;
    if (ph == PHASE_IDLE) {
        if (now_us - idle_since_us >= POLL_GAP_US) {
            start_request(now_us);
        }
        return ESC_NONE;
    }
    if (ph == PHASE_RX && rx_count == FRAME_LEN) {
        end_exchange(now_us);
        return parse(out);
    }
    if (now_us - poll_start_us > REPLY_TIMEOUT_US) {
        /* Silence is no frame (the caller times the ESC out); a partial reply is a bad one. */
        uint8_t partial = rx_count;
        end_exchange(now_us);
        return partial ? ESC_BAD : ESC_NONE;
    }
    return ESC_NONE;
}
