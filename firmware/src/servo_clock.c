/* Timer1 in fast PWM mode 14 (TOP = ICR1) at clk/8: one tick is 0.5 µs at 16 MHz, so the pulse
 * has 0.5 µs resolution and the period 2e6 / servo_hz ticks. The overflow interrupt (once per
 * period) advances the microsecond clock; micros() adds the running count. */
#include "servo_clock.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>

#include "config.h"

#define TICKS_PER_S 2000000UL

static uint16_t period_ticks;
static uint16_t pulse_us;
static volatile uint32_t base_us;
/* Half microseconds not yet in base_us: a period of an odd number of ticks ends mid-µs. */
static volatile uint8_t base_half;

void servo_clock_init(uint16_t servo_hz)
{
    period_ticks = (uint16_t)(TICKS_PER_S / servo_hz);
    pulse_us = PULSE_NEUTRAL_US;
    OCR1A = 2u * PULSE_NEUTRAL_US;
    ICR1 = period_ticks - 1u;
    TCNT1 = 0;
    TCCR1A = _BV(COM1A1) | _BV(WGM11);
    TCCR1B = _BV(WGM13) | _BV(WGM12) | _BV(CS11);
    TIMSK1 = _BV(TOIE1);
    DDRB |= _BV(PB1);
}

ISR(TIMER1_OVF_vect)
{
    uint8_t half = base_half + (uint8_t)(period_ticks & 1u);
    uint32_t us = base_us + (period_ticks >> 1);
    if (half >= 2u) {
        half -= 2u;
        ++us;
    }
    base_us = us;
    base_half = half;
}

void servo_set_us(uint16_t us)
{
    pulse_us = us;
    /* A 16-bit register write goes through Timer1's shared TEMP byte: no interrupt in between. */
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        OCR1A = 2u * us;
    }
}

uint16_t servo_get_us(void)
{
    return pulse_us;
}

uint16_t servo_clock_ticks(void)
{
    uint16_t t;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        t = TCNT1;
    }
    return t;
}

uint16_t servo_clock_period_ticks(void)
{
    return period_ticks;
}

uint32_t micros(void)
{
    uint32_t us;
    uint8_t half;
    uint16_t t;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        t = TCNT1;
        us = base_us;
        half = base_half;
        /* The counter wrapped but the overflow interrupt has not run yet. */
        if ((TIFR1 & _BV(TOV1)) && t < (period_ticks >> 1)) {
            us += period_ticks >> 1;
            half += (uint8_t)(period_ticks & 1u);
        }
    }
    return us + ((t + half) >> 1);
}
