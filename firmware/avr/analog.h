/* The analog inputs, converted once per millisecond in the background (ADC interrupt): battery
   voltage on A0 through the divider, optional Hall current sensors. Values in mV / mA. */
#ifndef ANALOG_H
#define ANALOG_H
#include <stdint.h>

void analog_init(void);
void analog_start_round(void);                 /* convert every channel once (every millisecond) */
int32_t analog_battery_mv(void);
int32_t analog_battery_current_ma(void);       /* 0 without BATTERY_CURRENT_HALL */
int32_t analog_motor_current_ma(uint8_t w);    /* wheel w, signed with its duty; 0 without sensors */

#endif
