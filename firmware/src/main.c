/* tfdd bridge firmware for the ATmega328P at 16 MHz (avr-libc, no Arduino core).
 *
 * Between the vehicle computer (USART0, the bridge protocol of docs/protocol.md) and one ESC:
 * drives the ESC's servo input (servo_clock.c) and reads its telemetry (esc_hott.c or esc_kiss.c).
 * The pulse is neutral for ARMING_MS after every reset, whenever the host's command is older than
 * its timeout (ESC_TIMEOUT), and while the ESC's telemetry is lost (a fault, flagged ADC_FAULT and
 * RPM_FAULT). The AVR watchdog resets a loop that stops running, which restarts in neutral. */
#include <avr/eeprom.h>
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>
#include <stdbool.h>
#include <stdint.h>

#include "config.h"
#include "esc.h"
#include "host_link.h"
#include "servo_clock.h"
#include "wake.h"

/* Rates stored in EEPROM at address 0 (all little-endian): 'T', 'B', telemetry rate in Hz (u8),
 * servo frame rate in Hz (u16), and a check byte, the complement of the sum of the five before
 * it. A blank or invalid block means the defaults of config.h. */
#define EEPROM_CONFIG_LEN 6u

struct rates {
    uint8_t telemetry_hz;
    uint16_t servo_hz;
};

struct bridge {
    uint32_t boot_us;
    uint32_t command_us;       /* when the last valid command arrived (boot before any) */
    uint16_t command_timeout_ms;
    uint16_t command_pulse_us;
    bool command_clamped;
    struct esc_reading reading;
    bool reading_valid;        /* a good reading arrived and none failed since */
    bool ever_read;
    uint32_t reading_us;
    int8_t rpm_sign;           /* the direction of the last non-neutral pulse */
    uint32_t next_telemetry_us;
    uint32_t telemetry_period_us;
    bool reset_pending;        /* the next telemetry frame is the first after a reset */
};

static struct bridge bridge;
volatile uint8_t bridge_wake;

/* The watchdog stays enabled across a watchdog reset: switch it off before anything else. */
void early_watchdog_off(void) __attribute__((naked, used, section(".init3")));
void early_watchdog_off(void)
{
    MCUSR = 0;
    wdt_disable();
}

static struct rates load_rates(void)
{
    uint8_t b[EEPROM_CONFIG_LEN];
    eeprom_read_block(b, (const void *)0, sizeof b);
    uint8_t sum = 0;
    for (uint8_t i = 0; i < EEPROM_CONFIG_LEN - 1u; ++i) {
        sum = (uint8_t)(sum + b[i]);
    }
    struct rates r = {
        .telemetry_hz = b[2],
        .servo_hz = (uint16_t)(b[3] | ((uint16_t)b[4] << 8)),
    };
    bool valid = b[0] == 'T' && b[1] == 'B' && (uint8_t)(sum + b[5]) == 0xFFu
        && r.telemetry_hz >= TELEMETRY_HZ_MIN && r.telemetry_hz <= TELEMETRY_HZ_MAX
        && r.servo_hz >= SERVO_HZ_MIN && r.servo_hz <= SERVO_HZ_MAX;
    if (!valid) {
        r.telemetry_hz = DEFAULT_TELEMETRY_HZ;
        r.servo_hz = DEFAULT_SERVO_HZ;
    }
    return r;
}

static bool older_than(uint32_t now_us, uint32_t then_us, uint32_t ms)
{
    return now_us - then_us > ms * 1000UL;
}

static void apply_command(const struct command *c, uint32_t now_us)
{
    uint16_t pulse = c->pulse_us;
    bridge.command_clamped = pulse < PULSE_MIN_US || pulse > PULSE_MAX_US;
    if (pulse < PULSE_MIN_US) {
        pulse = PULSE_MIN_US;
    } else if (pulse > PULSE_MAX_US) {
        pulse = PULSE_MAX_US;
    }
    bridge.command_pulse_us = pulse;
    /* A zero timeout would switch the watchdog off: keep the one in force. */
    if (c->timeout_ms > 0u) {
        bridge.command_timeout_ms = c->timeout_ms;
    }
    bridge.command_us = now_us;
}

static void send_telemetry(uint32_t now_us, bool timed_out)
{
    struct telemetry t = {
        .timestamp_us = now_us,
        .pulse_us = servo_get_us(),
        .status = 0,
    };
    if (timed_out) {
        t.status |= STATUS_ESC_TIMEOUT;
    }
    if (bridge.command_clamped && !timed_out) {
        t.status |= STATUS_CMD_CLAMPED;
    }
    if (bridge.reset_pending) {
        t.status |= STATUS_RESET;
        bridge.reset_pending = false;
    }
    if (bridge.reading_valid) {
        const struct esc_reading *r = &bridge.reading;
        t.voltage_cv = r->voltage_cv;
        t.current_ca = (int16_t)r->current_ca;
        t.rpm = bridge.rpm_sign * (int32_t)r->rpm;
        t.temperature_cc = r->temperature_cc;
    } else {
        /* No value is better than a wrong one: the flags tell the host why. */
        t.status |= STATUS_ADC_FAULT | STATUS_RPM_FAULT;
    }
    host_link_send_telemetry(&t);
}

/* One pass of the main loop (kept out of line: the co-simulation times each pass from its entry
 * to the sleep that follows). */
static void __attribute__((noinline)) bridge_step(void)
{
    uint32_t now = micros();
    struct command command;
    if (host_link_poll(&command)) {
        apply_command(&command, now);
    }

    struct esc_reading reading;
    enum esc_result result = esc_poll(now, &reading);
    if (result == ESC_NEW) {
        bridge.reading = reading;
        bridge.reading_valid = true;
        bridge.ever_read = true;
        bridge.reading_us = now;
    } else if (result == ESC_BAD) {
        bridge.reading_valid = false;
    }
    bool esc_lost = !bridge.ever_read || older_than(now, bridge.reading_us, ESC_LOST_MS);
    if (esc_lost) {
        bridge.reading_valid = false;
    }
    bool timed_out = older_than(now, bridge.command_us, bridge.command_timeout_ms);
    bool arming = !older_than(now, bridge.boot_us, ARMING_MS);

    uint16_t pulse = arming || timed_out || esc_lost ? PULSE_NEUTRAL_US : bridge.command_pulse_us;
    servo_set_us(pulse);
    if (pulse > PULSE_NEUTRAL_US) {
        bridge.rpm_sign = 1;
    } else if (pulse < PULSE_NEUTRAL_US) {
        bridge.rpm_sign = -1;
    }

    if ((int32_t)(now - bridge.next_telemetry_us) >= 0) {
        send_telemetry(now, timed_out);
        bridge.next_telemetry_us += bridge.telemetry_period_us;
        /* After a stall, restart the schedule instead of sending a burst. */
        if ((int32_t)(now - bridge.next_telemetry_us) > (int32_t)(4u * bridge.telemetry_period_us)) {
            bridge.next_telemetry_us = now + bridge.telemetry_period_us;
        }
    }
}

/* Timer0 wakes the sleeping loop every 1.024 ms (CTC, clk/1024, 16 counts), so schedules are
 * kept to about a millisecond while the CPU idles between interrupts. */
static void wake_tick_init(void)
{
    OCR0A = 15u;
    TCCR0A = _BV(WGM01);
    TCCR0B = _BV(CS02) | _BV(CS00);
    TIMSK0 = _BV(OCIE0A);
}

ISR(TIMER0_COMPA_vect)
{
    wake_main_loop();
}

/* Sleep until an interrupt brings work (wake.h). Interrupts stay off between the check and the
 * sleep instruction (SEI takes effect after the next one), so no wake-up is missed. */
static void idle(void)
{
    cli();
    while (!bridge_wake && !host_link_rx_pending()) {
        sleep_enable();
        sei();
        sleep_cpu();
        sleep_disable();
        cli();
    }
    bridge_wake = 0;
    sei();
}

int main(void)
{
    struct rates rates = load_rates();
    servo_clock_init(rates.servo_hz);
    host_link_init();
    esc_init();
    wake_tick_init();
    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();
    uint32_t now = micros();
    bridge = (struct bridge){
        .boot_us = now,
        .command_us = now,
        .command_timeout_ms = DEFAULT_COMMAND_TIMEOUT_MS,
        .command_pulse_us = PULSE_NEUTRAL_US,
        .rpm_sign = 1,
        .next_telemetry_us = now,
        .telemetry_period_us = 1000000UL / rates.telemetry_hz,
        .reset_pending = true,
    };
    /* 60 ms: far above the loop's worst case (README), short enough to stop a runaway thruster
     * fast. */
    wdt_enable(WDTO_60MS);
    for (;;) {
        wdt_reset();
        bridge_step();
        idle();
    }
}
