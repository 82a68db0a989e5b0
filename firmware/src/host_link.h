/* The host link on USART0 (115200 8N1): the tfdd v1 bridge protocol of docs/protocol.md. */
#ifndef TFDD_HOST_LINK_H
#define TFDD_HOST_LINK_H

#include <avr/io.h>
#include <stdbool.h>
#include <stdint.h>

#include "wake.h"

#define STATUS_ESC_TIMEOUT 0x01u
#define STATUS_ADC_FAULT 0x02u
#define STATUS_RPM_FAULT 0x04u
#define STATUS_CMD_CLAMPED 0x08u
#define STATUS_RESET 0x10u

/* One telemetry sample in wire units. */
struct telemetry {
    uint32_t timestamp_us;
    uint16_t pulse_us;
    uint16_t voltage_cv;  /* 0.01 V */
    int16_t current_ca;   /* 0.01 A */
    int32_t rpm;
    int16_t temperature_cc; /* 0.01 °C */
    uint8_t status;
};

/* A command frame that passed every check. */
struct command {
    uint16_t pulse_us;
    uint16_t timeout_ms;
};

void host_link_init(void);

/* Decode at most a bounded number of received bytes; true with *out filled when they complete
 * a command frame. Answers a VERSION_QUERY itself. */
bool host_link_poll(struct command *out);

/* Queue a telemetry frame; a frame that does not fit the transmit buffer is dropped whole
 * (its sequence number is spent, so the host counts it lost). */
void host_link_send_telemetry(const struct telemetry *t);

/* The receive ring, filled by host_link_service_rx (size a power of two). */
#define HOST_RX_RING 64u
extern volatile uint8_t host_rx_ring[HOST_RX_RING];
extern volatile uint8_t host_rx_head;
extern volatile uint8_t host_rx_tail;

/* Received bytes wait to be decoded (host_link_poll takes a bounded number per call). */
static inline bool host_link_rx_pending(void)
{
    return host_rx_head != host_rx_tail;
}

/* Move a byte waiting in UDR0 into the receive ring; a full ring drops it (its frame then fails
 * the CRC). Inline, so that an interrupt that blocks for most of a character time (the KISS bit
 * sampler) can call it without saving every register on entry. Call with interrupts off. */
static inline void host_link_service_rx(void)
{
    if (!(UCSR0A & _BV(RXC0))) {
        return;
    }
    uint8_t byte = UDR0;
    uint8_t next = (uint8_t)((host_rx_head + 1u) & (HOST_RX_RING - 1u));
    if (next != host_rx_tail) {
        host_rx_ring[host_rx_head] = byte;
        host_rx_head = next;
    }
    wake_main_loop();
}

#endif
