// neck_fw -- wire protocol constants. PROTOCOL.md is the normative description;
// neck_env/rig/protocol.py mirrors these numbers on the host side.
#pragma once

#include <stdint.h>

#define PROTOCOL_VERSION 1

// Frame: SYNC0 SYNC1 VER TYPE SEQ LEN PAYLOAD[LEN] CRC_LO CRC_HI
// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) over VER..end of payload.
#define FRAME_SYNC0 0xA5
#define FRAME_SYNC1 0x5A
#define FRAME_HEADER_LEN 6
#define FRAME_CRC_LEN 2
#define FRAME_MAX_PAYLOAD 64
#define FRAME_MAX_LEN (FRAME_HEADER_LEN + FRAME_MAX_PAYLOAD + FRAME_CRC_LEN)
// A partial frame older than this is dropped (counted as a bad frame).
#define FRAME_STALE_MS 100UL

// Host -> MCU
enum : uint8_t {
  MSG_HELLO = 0x01,        // len 0
  MSG_SET_RELAYS = 0x02,   // len 2: mask, mask ^ 0xFF
  MSG_SET_DUTY = 0x03,     // len 6: u16 permille x3
  MSG_STREAM = 0x04,       // len 1: rate Hz (0 = off)
  MSG_STOP = 0x05,         // len 0
  MSG_HEARTBEAT = 0x06,    // len 0
  MSG_CONFIG = 0x07,       // len 1: thermistor-fitted mask; len 5: + u16 cut, u16 release ADC
  MSG_CLEAR_FAULTS = 0x08, // len 0
  MSG_GET_STATUS = 0x09,   // len 0 -> one STATUS frame
  MSG_WDT_TEST = 0x0A,     // len 4: 'W' 'D' 'T' '!'
};

// MCU -> host
enum : uint8_t {
  MSG_BOOT = 0x80,
  MSG_HELLO_REPLY = 0x81,
  MSG_ACK = 0x82,
  MSG_NAK = 0x83,
  MSG_TELEMETRY = 0x84,    // streamed; header SEQ = MCU frame counter
  MSG_STATUS = 0x85,       // reply to GET_STATUS, TELEMETRY payload, SEQ echoed
};

// NAK error codes
enum : uint8_t {
  ERR_BAD_LENGTH = 1,
  ERR_UNKNOWN_TYPE = 2,
  ERR_BAD_VALUE = 3,
  ERR_BAD_VERSION = 4,
};

// Fault flag bits (u16 in TELEMETRY)
enum : uint16_t {
  FAULT_HEARTBEAT_LOST = 1u << 0,  // latched; cleared by the next valid frame
  FAULT_IMU_MISSING = 1u << 1,     // live: 0x68 does not ACK (address or data NACK)
  FAULT_IMU_BAD_ID = 1u << 2,      // live: WHO_AM_I != 0x68
  FAULT_IMU_READ = 1u << 3,        // live: read/config failure or bus timeout
  FAULT_ONTIME_LOCKOUT = 1u << 4,  // live: some muscle in on-time lock-out
  FAULT_DUTY_LIMIT = 1u << 5,      // live: some muscle held off by the duty limiter
  FAULT_OVERTEMP = 1u << 6,        // live: some muscle cut by over-temperature
  FAULT_THERM_SENSOR = 1u << 7,    // live: a fitted thermistor reads open
  FAULT_WDT_RESET = 1u << 8,       // latched since boot: last reset was the AVR watchdog
  FAULT_SAFETY_TRIP = 1u << 9,     // latched: firmware forced a muscle off since CLEAR_FAULTS
  FAULT_TX_OVERFLOW = 1u << 10,    // latched: telemetry frame dropped (link too slow)
};

#define WDT_TEST_MAGIC0 'W'
#define WDT_TEST_MAGIC1 'D'
#define WDT_TEST_MAGIC2 'T'
#define WDT_TEST_MAGIC3 '!'
