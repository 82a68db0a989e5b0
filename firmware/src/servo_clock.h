/* Timer1: the ESC servo pulse on OC1A (PB1, Arduino D9) and the bridge's microsecond clock. */
#ifndef TFDD_SERVO_CLOCK_H
#define TFDD_SERVO_CLOCK_H

#include <stdint.h>

/* Start Timer1 at servo_hz (50..400 Hz) with the neutral pulse. */
void servo_clock_init(uint16_t servo_hz);

/* Pulse width of the next servo periods, µs; takes effect at the start of the next period. */
void servo_set_us(uint16_t pulse_us);

/* The pulse width last set, µs. */
uint16_t servo_get_us(void);

/* Microseconds since start, wrapping at 2^32 (callable from interrupts). */
uint32_t micros(void);

/* Timer1 ticks (0.5 µs) since start of the current servo period, and the period in ticks:
 * the cheap time base of the KISS bit sampler. */
uint16_t servo_clock_ticks(void);
uint16_t servo_clock_period_ticks(void);

#endif
