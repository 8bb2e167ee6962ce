#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>
#include "host_uart.h"

#define RX_SIZE 128u   /* powers of two: the indices wrap by masking */
#define TX_SIZE 256u

static volatile uint8_t rx[RX_SIZE], rx_head, rx_tail;
static volatile uint8_t tx[TX_SIZE], tx_head, tx_tail;  /* uint8_t indices wrap at 256 */
static volatile uint16_t rx_overruns;

void host_uart_init(uint32_t baud) {
    UCSR0A = _BV(U2X0);
    UBRR0 = (uint16_t)((F_CPU / 4 / baud - 1) / 2);  /* U2X, rounded: 16 at 115200 (+2.1 %, as the Arduino core) */
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);              /* 8N1 */
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

ISR(USART0_RX_vect) {
    uint8_t st = UCSR0A;
    uint8_t b = UDR0;
    if (st & (_BV(FE0) | _BV(DOR0)))
        b = 0xFF;  /* a framing error or overrun corrupts the frame; its CRC will reject it */
    uint8_t next = (uint8_t)((rx_head + 1) & (RX_SIZE - 1));
    if (next == rx_tail) {
        rx_overruns++;
        return;
    }
    rx[rx_head] = b;
    rx_head = next;
}

uint8_t host_uart_available(void) { return rx_head != rx_tail; }

uint8_t host_uart_read(uint8_t *buf, uint8_t max) {
    uint8_t n = 0;
    while (n < max && rx_tail != rx_head) {
        buf[n++] = rx[rx_tail];
        rx_tail = (uint8_t)((rx_tail + 1) & (RX_SIZE - 1));
    }
    return n;
}

ISR(USART0_UDRE_vect) {
    if (tx_tail == tx_head) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx[tx_tail++];
}

uint8_t host_uart_write(const uint8_t *b, uint8_t n) {
    uint8_t free_bytes;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { free_bytes = (uint8_t)(tx_tail - tx_head - 1); }
    if (n > free_bytes)
        return 0;
    for (uint8_t i = 0; i < n; i++)
        tx[tx_head++] = b[i];  /* only this side moves tx_head */
    UCSR0B |= _BV(UDRIE0);
    return 1;
}
