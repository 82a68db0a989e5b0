/* KISS / BLHeli_32 ESC telemetry (build option -DESC_TELEMETRY_KISS): 10-byte frames at 115200
 * baud 8N1 that the ESC sends on its own (docs/protocol.md has the layout), received on PD2.
 *
 * A bit lasts 139 CPU cycles, too short for an interrupt per bit: the start edge (INT0) enters an
 * interrupt that samples the byte's 8 data bits itself, timed by Timer1's 0.5 µs count, and
 * returns in the stop bit (about 75 µs, less than the 85 µs of a host character; it also takes a
 * host byte waiting in UDR0, so none is lost). The interrupt calls no function, so its entry is
 * short and fixed: it reads the timer about 6 ticks (50 cycles with avr-gcc 7.3 -Os) after the
 * edge. A frame ends with the silence
 * after it (the main loop sees the byte count stop growing). */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>
#include <util/crc16.h>

#include "esc.h"
#include "host_link.h"

#define FRAME_LEN 10u
/* Timer1 ticks (0.5 µs) from the start edge to the middle of data bit k, (1.5 + k) * 17.36,
 * less the 6 ticks from the edge to the interrupt's first timer read. */
#define SAMPLE_TICKS(k) ((uint8_t)(((150UL + 100UL * (k)) * 1736UL + 5000UL) / 10000UL - 6UL))
/* No new byte for this long: the frame is over. */
#define FRAME_GAP_US 2000UL

static volatile uint8_t frame[FRAME_LEN];
/* Bytes received in the current frame; FRAME_LEN + 1 when more came than a frame holds. */
static volatile uint8_t count;
static uint8_t seen;
static uint32_t seen_change_us;
static const uint8_t sample_ticks[8] = {
    SAMPLE_TICKS(0), SAMPLE_TICKS(1), SAMPLE_TICKS(2), SAMPLE_TICKS(3),
    SAMPLE_TICKS(4), SAMPLE_TICKS(5), SAMPLE_TICKS(6), SAMPLE_TICKS(7),
};

void esc_init(void)
{
    DDRD &= (uint8_t)~_BV(PD2);
    PORTD |= _BV(PD2);
    EICRA = (uint8_t)((EICRA & (uint8_t)~(_BV(ISC01) | _BV(ISC00))) | _BV(ISC01));
    EIFR = _BV(INTF0);
    EIMSK |= _BV(INT0);
}

ISR(INT0_vect)
{
    uint16_t t0 = TCNT1;
    uint16_t period = ICR1 + 1u;
    uint8_t byte = 0;
    for (uint8_t k = 0; k < 8u; ++k) {
        uint8_t due = sample_ticks[k];
        for (;;) {
            uint16_t t = TCNT1;
            uint16_t elapsed = t >= t0 ? (uint16_t)(t - t0) : (uint16_t)(t + period - t0);
            if (elapsed >= due) {
                break;
            }
        }
        if (PIND & _BV(PD2)) {
            byte = (uint8_t)(byte | (uint8_t)(1u << k));
        }
    }
    /* The edge flag was set again by the falling data bits of this byte. */
    EIFR = _BV(INTF0);
    uint8_t n = count;
    if (n < FRAME_LEN) {
        frame[n] = byte;
    }
    if (n <= FRAME_LEN) {
        count = (uint8_t)(n + 1u);
    }
    host_link_service_rx();
}

static uint16_t be16(const uint8_t *f, uint8_t at)
{
    return (uint16_t)(((uint16_t)f[at] << 8) | f[at + 1u]);
}

enum esc_result esc_poll(uint32_t now_us, struct esc_reading *out)
{
    uint8_t n = count;
    if (n != seen) {
        seen = n;
        seen_change_us = now_us;
    }
    if (n == 0u || now_us - seen_change_us < FRAME_GAP_US) {
        return ESC_NONE;
    }
    uint8_t f[FRAME_LEN];
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        for (uint8_t i = 0; i < FRAME_LEN; ++i) {
            f[i] = frame[i];
        }
        count = 0;
    }
    seen = 0;
    if (n != FRAME_LEN) {
        return ESC_BAD;
    }
    uint8_t crc = 0;
    for (uint8_t i = 0; i < FRAME_LEN - 1u; ++i) {
        crc = _crc8_ccitt_update(crc, f[i]);
    }
    if (crc != f[FRAME_LEN - 1u]) {
        return ESC_BAD;
    }
    uint32_t rpm = (uint32_t)be16(f, 7) * 100u / POLE_PAIRS;
    struct esc_reading r = {
        .voltage_cv = be16(f, 1),
        .current_ca = be16(f, 3),
        .rpm = rpm > RPM_MAX ? RPM_MAX + 1u : (uint16_t)rpm,
        .temperature_cc = (int16_t)(f[0] * 100),
    };
    if (!esc_reading_plausible(&r)) {
        return ESC_BAD;
    }
    *out = r;
    return ESC_NEW;
}
