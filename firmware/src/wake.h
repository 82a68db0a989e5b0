/* The main loop sleeps until an interrupt brings it work: the 1 ms tick, a host byte, a complete
 * ESC frame. Other interrupts (bit timing, transmit, servo period) leave it asleep. */
#ifndef TFDD_WAKE_H
#define TFDD_WAKE_H

#include <stdint.h>

extern volatile uint8_t bridge_wake;

/* Call from an interrupt: the main loop runs a pass once the interrupt returns. */
static inline void wake_main_loop(void)
{
    bridge_wake = 1;
}

#endif
