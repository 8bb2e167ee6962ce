/* The host link on USART0 (USB serial): interrupt-driven rings, whole frames or nothing. */
#ifndef HOST_UART_H
#define HOST_UART_H
#include <stdint.h>

void host_uart_init(uint32_t baud);
uint8_t host_uart_read(uint8_t *buf, uint8_t max);   /* bytes received so far (up to max) */
uint8_t host_uart_available(void);
uint8_t host_uart_write(const uint8_t *b, uint8_t n); /* 0 if n bytes do not fit */

#endif
