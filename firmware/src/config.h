// neck_fw -- compile-time configuration: pins, safety limits, IMU setup.
//
// Every number a host may need to know is also reported in the HELLO reply
// (see PROTOCOL.md), so the host never has to duplicate this file.
#pragma once

#include <avr/io.h>

// ---------------------------------------------------------------------------
// Firmware identity
// ---------------------------------------------------------------------------
#define FW_VERSION_MAJOR 1
#define FW_VERSION_MINOR 1
#define FW_VERSION_PATCH 0

// ---------------------------------------------------------------------------
// Relay outputs: muscle k (0, 1, 2) -> Arduino D5, D6, D7 = PD5, PD6, PD7.
// Active HIGH. All three live on one port so they can be switched in a single
// register write (no window where a half-updated mask is on the pins).
// ---------------------------------------------------------------------------
#define RELAY_PORT PORTD
#define RELAY_DDR DDRD
#define RELAY_PINREG PIND
#define RELAY0_BIT PD5
#define RELAY1_BIT PD6
#define RELAY2_BIT PD7
#define RELAY_PORT_MASK (_BV(RELAY0_BIT) | _BV(RELAY1_BIT) | _BV(RELAY2_BIT))
#define RELAY0_ARDUINO_PIN 5
#define RELAY1_ARDUINO_PIN 6
#define RELAY2_ARDUINO_PIN 7
#define N_MUSCLES 3

// ---------------------------------------------------------------------------
// Serial link
// ---------------------------------------------------------------------------
#define SERIAL_BAUD 115200UL

// ---------------------------------------------------------------------------
// Safety limits (all times in ms of MCU time, millis()).
// ---------------------------------------------------------------------------
// Host silence after which everything is switched off.
#define HEARTBEAT_TIMEOUT_MS 250UL
// Time-proportional switching window for SET_DUTY.
#define DUTY_WINDOW_MS 1000U
// Largest duty a SET_DUTY may apply (permille of the window); larger requests
// are clamped and reported in the ACK.
#define DUTY_MAX_PERMILLE 800U
// Longest continuous on-time of one muscle; then it is forced off and locked
// out for LOCKOUT_MS (commands to switch it on are refused meanwhile).
#define ONTIME_CAP_MS 10000UL
#define LOCKOUT_MS 10000UL
// Sustained-duty limiter (leaky bucket, any command mix): the bucket gains 1
// per ms on and loses DUTY_BUCKET_DRAIN per ms off, so it only grows while the
// long-run duty exceeds DRAIN/(1+DRAIN) = 80 %. When it reaches
// DUTY_BUCKET_CAP_MS the muscle is forced off and refused until the bucket has
// drained back to zero.
#define DUTY_BUCKET_CAP_MS 20000L
#define DUTY_BUCKET_DRAIN 4L

// ---------------------------------------------------------------------------
// Thermistors on A0..A2 (optional; CONFIG tells the firmware which are fitted).
// Divider: 10 kOhm fixed resistor from +5 V to the pin, NTC (10 kOhm at 25 C,
// beta 3950) from the pin to GND. ADC = 1023 * R_ntc / (R_ntc + 10k), so a hot
// NTC reads LOW.
//   110 C -> R_ntc = 529 Ohm  -> ADC 51.4  (default cut at ADC <= 51)
//   100 C -> R_ntc = 698 Ohm  -> ADC 66.7  (default release when ADC >= 67)
// The host may move the cut with CONFIG (the env sends its cutoff_C, 160 C by
// default: ADC 16, released at 150 C, ADC 20), but never hotter than
// THERM_CUT_ADC_MIN: 14 counts = 167 C, the firmware's own maximum. Near
// 160 C one ADC count is ~3 C, so the cut is good to about +-2 C there.
// An open NTC reads near 1023 (THERM_OPEN_ADC): treated as a sensor fault and
// the muscle is kept off (fail safe). A shorted NTC reads ~0 = "hot" = cut.
// ---------------------------------------------------------------------------
#define THERM_CUT_ADC 51U
#define THERM_RELEASE_ADC 67U
#define THERM_CUT_ADC_MIN 14U       // hottest cut a host may set (~167 C)
#define THERM_HYSTERESIS_ADC_MIN 2U // release at least this many counts above the cut
#define THERM_OPEN_ADC 1015U
#define THERM_CONFIRM_SAMPLES 3   // consecutive samples before acting (noise)
#define ADC_PERIOD_MS 10UL

// ---------------------------------------------------------------------------
// MPU6050
// ---------------------------------------------------------------------------
#define IMU_ADDR 0x68
#define IMU_WHO_AM_I_VALUE 0x68
#define IMU_READ_PERIOD_MS 5UL     // 200 Hz reads (sensor output rate 200 Hz)
#define IMU_RETRY_PERIOD_MS 1000UL // re-probe a missing/failed IMU this often
#define I2C_CLOCK_HZ 400000UL
#define I2C_TIMEOUT_US 3000UL      // Wire timeout: a stuck bus never hangs loop()
// Register values written at init.
#define IMU_PWR_MGMT_1_VAL 0x01    // awake, clock = PLL with X gyro reference
#define IMU_SMPLRT_DIV_VAL 4       // 1 kHz / (1 + 4) = 200 Hz with the DLPF on
#define IMU_CONFIG_VAL 0x03        // DLPF 44 Hz accel / 42 Hz gyro
#define IMU_GYRO_CONFIG_VAL 0x08   // FS_SEL = 1: +-500 deg/s, 65.5 LSB/(deg/s)
#define IMU_ACCEL_CONFIG_VAL 0x08  // AFS_SEL = 1: +-4 g, 8192 LSB/g

// ---------------------------------------------------------------------------
// Telemetry
// ---------------------------------------------------------------------------
#define STREAM_MAX_HZ 100

// ---------------------------------------------------------------------------
// AVR hardware watchdog: interrupt + reset mode, 250 ms. A hung loop first
// gets the WDT interrupt (relays off at once, trip counted in .noinit RAM),
// then a reset 250 ms later.
// ---------------------------------------------------------------------------
#define HW_WDT_PRESCALER (_BV(WDP2))  // 250 ms
