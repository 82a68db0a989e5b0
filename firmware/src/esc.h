/* The ESC's telemetry, read on a software serial pin (PD2 / INT0, Arduino D2): Graupner HoTT
 * (esc_hott.c, the default) or KISS / BLHeli_32 10-byte frames (esc_kiss.c, -DESC_TELEMETRY_KISS). */
#ifndef TFDD_ESC_H
#define TFDD_ESC_H

#include <stdint.h>

#include "config.h"

/* One plausible reading in wire units; rpm and current are magnitudes (neither protocol has a
 * sign). */
struct esc_reading {
    uint16_t voltage_cv;    /* 0.01 V */
    uint16_t current_ca;    /* 0.01 A */
    uint16_t rpm;
    int16_t temperature_cc; /* 0.01 °C */
};

enum esc_result {
    ESC_NONE,   /* nothing new */
    ESC_NEW,    /* a valid, plausible reading in *out */
    ESC_BAD,    /* a frame failed: framing, layout, checksum or range; its values are dropped */
};

void esc_init(void);

/* Advance the telemetry link (polls, timeouts) and report a completed frame. */
enum esc_result esc_poll(uint32_t now_us, struct esc_reading *out);

/* Range check shared by both protocols (config.h limits). */
static inline uint8_t esc_reading_plausible(const struct esc_reading *r)
{
    return r->voltage_cv <= VOLTAGE_MAX_CV && r->current_ca <= CURRENT_MAX_CA && r->rpm <= RPM_MAX
        && r->temperature_cc >= TEMPERATURE_MIN_CC && r->temperature_cc <= TEMPERATURE_MAX_CC;
}

#endif
