/* Build-time settings of the bridge firmware (each can be overridden with -DNAME=value). */
#ifndef TFDD_CONFIG_H
#define TFDD_CONFIG_H

#define FW_VERSION_MAJOR 1
#define FW_VERSION_MINOR 0
#define FW_VERSION_PATCH 0

/* ESC servo pulse, µs: neutral, and the limits a command is clamped to (CMD_CLAMPED). */
#define PULSE_NEUTRAL_US 1500u
#define PULSE_MIN_US 1100u
#define PULSE_MAX_US 1900u

/* Neutral after every reset for this long, whatever the host commands: the ESC arms on a
 * steady neutral signal. */
#ifndef ARMING_MS
#define ARMING_MS 2000u
#endif

/* Bridge watchdog until a command frame sets its own timeout, ms. */
#define DEFAULT_COMMAND_TIMEOUT_MS 1000u

/* No valid ESC telemetry for this long is a fault: neutral until the ESC answers again. */
#ifndef ESC_LOST_MS
#define ESC_LOST_MS 500u
#endif

/* Rates used when the EEPROM holds no valid configuration (see eeprom_config in main.c). */
#define DEFAULT_TELEMETRY_HZ 50u
#define DEFAULT_SERVO_HZ 50u
#define TELEMETRY_HZ_MIN 10u
#define TELEMETRY_HZ_MAX 100u
#define SERVO_HZ_MIN 50u
#define SERVO_HZ_MAX 400u

/* Plausible ESC readings, the host's PLAUSIBLE_LIMITS (core/protocol.py) in wire units:
 * 0.01 V, 0.01 A, rpm, 0.01 °C. A reading outside them is refused and flagged. */
#define VOLTAGE_MAX_CV 6000u
#define CURRENT_MAX_CA 6000u
#define RPM_MAX 10000u
#define TEMPERATURE_MIN_CC (-2000)
#define TEMPERATURE_MAX_CC 12500

/* Motor pole pairs, to turn KISS eRPM into shaft rpm (7 for the T100/T200). */
#ifndef POLE_PAIRS
#define POLE_PAIRS 7u
#endif

#endif
