// neck_fw -- Arduino UNO (ATmega328P) firmware for the SMA-spring robotic neck.
//
// Three relays switch a DC supply (4-8 A) through the three SMA muscles; an
// MPU6050 on the head gives tilt. The host (neck_env.rig) talks the binary
// protocol described in ../PROTOCOL.md at 115200 baud.
//
// Safety is the firmware's job, not the host's: the host may crash, the USB
// cable may fall out, the serial line may carry garbage. Hence:
//   * relays are driven LOW before anything else runs (.init3, below);
//   * only CRC-checked, well-formed frames are ever acted on;
//   * no valid frame for HEARTBEAT_TIMEOUT_MS -> everything off;
//   * continuous on-time cap + lock-out, duty clamp, sustained-duty limiter;
//   * optional thermistor over-temperature cut;
//   * the AVR watchdog catches a hung loop (its ISR switches the relays off
//     at once, the reset follows).
//
// Written as a plain .cpp (no Arduino IDE prototype generation): every
// function is defined before use.

#include <Arduino.h>
#include <Wire.h>
#include <avr/interrupt.h>
#include <avr/wdt.h>
#include <string.h>
#include <util/atomic.h>
#include <util/crc16.h>

#include "config.h"
#include "protocol.h"

// ===========================================================================
// Boot: relays off first, reset cause captured, watchdog disarmed.
// ===========================================================================

// .noinit survives a watchdog or external reset (not a power cycle), so the
// firmware can count watchdog trips across resets. NV_MAGIC tells valid
// contents from power-on garbage.
#define NV_MAGIC 0x4E4Bu        // "NK"
#define NV_WDT_FLAG_MAGIC 0xD0u // set by the WDT ISR just before the reset
static uint16_t nv_magic __attribute__((section(".noinit")));
static uint16_t nv_wdt_trips __attribute__((section(".noinit")));
static uint8_t nv_wdt_flag __attribute__((section(".noinit")));
// Written in .init3, i.e. before .bss is zeroed, so it must live in .noinit.
static uint8_t boot_mcusr __attribute__((section(".noinit")));

// Runs from the reset vector before the C runtime initialises RAM, before
// main(), init(), Serial and Wire. The pins are inputs (high impedance) out of
// reset; make them driven LOW outputs right away. MCUSR must be cleared before
// the watchdog can be disabled: after a watchdog reset WDRF forces WDE on with
// the shortest (16 ms) timeout, and the normal start-up would not finish in
// time -- a boot loop.
extern "C" void early_init(void) __attribute__((naked, used, section(".init3")));
extern "C" void early_init(void) {
  RELAY_PORT &= (uint8_t)~RELAY_PORT_MASK;
  RELAY_DDR |= RELAY_PORT_MASK;
  boot_mcusr = MCUSR;
  MCUSR = 0;
  wdt_disable();
}

// Hardware-watchdog interrupt (interrupt + reset mode): the main loop has not
// kicked the dog for 250 ms. Switch the muscles off now -- the reset only comes
// one more period later -- and leave a note for the next boot.
ISR(WDT_vect) {
  RELAY_PORT &= (uint8_t)~RELAY_PORT_MASK;
  nv_wdt_flag = NV_WDT_FLAG_MAGIC;
  nv_wdt_trips++;
}

static void hw_watchdog_start(void) {
  // Timed sequence: WDCE|WDE, then the new value within four cycles.
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
    wdt_reset();
    WDTCSR = _BV(WDCE) | _BV(WDE);
    WDTCSR = _BV(WDIE) | _BV(WDE) | HW_WDT_PRESCALER;
  }
}

// ===========================================================================
// State
// ===========================================================================

enum : uint8_t { MODE_OFF = 0, MODE_DIRECT = 1, MODE_DUTY = 2 };

struct Muscle {
  uint8_t mode;           // MODE_*
  uint16_t duty;          // permille actually applied (after the clamp)
  bool on;                // output state written to the pin
  uint32_t on_since;      // millis() when the output last went on
  bool locked;            // on-time lock-out active
  uint32_t lock_until;    // end of the lock-out
  int32_t bucket;         // sustained-duty limiter level (ms-equivalents)
  bool bucket_trip;       // held off until the bucket is empty
  bool overtemp;          // over-temperature cut active
  bool therm_open;        // fitted thermistor reads open
  uint8_t hot_count;      // consecutive samples at/over the cut threshold
  uint8_t open_count;     // consecutive samples reading open
};

static Muscle mus[N_MUSCLES];
static uint32_t mus_last_update;

// Link
static uint8_t rx_buf[FRAME_MAX_LEN];
static uint8_t rx_len;
static uint32_t rx_last_byte_ms;
static uint32_t last_valid_ms;
static bool link_armed;          // a valid frame has been seen; watchdog running
static uint16_t bad_frames;
static uint8_t tx_seq;           // header SEQ of unsolicited frames

// Telemetry
static uint8_t stream_hz;
static uint32_t stream_next_ms;
static uint16_t telem_seq;

// Faults
static uint16_t latched_faults;  // HEARTBEAT_LOST, WDT_RESET, SAFETY_TRIP, TX_OVERFLOW

// IMU
static bool imu_ok;
static uint16_t imu_fault;       // one of FAULT_IMU_* while !imu_ok
static uint32_t imu_next_ms;     // next read (ok) or next probe (fault)
static uint32_t imu_check_ms;    // next health check of WHO_AM_I / PWR_MGMT_1
static int16_t imu_raw[7];       // ax ay az temp gx gy gz (register order)
static uint16_t imu_errors;

// Thermistors
static uint8_t therm_mask;       // fitted thermistors (bit k = muscle k)
static uint16_t therm_cut_adc = THERM_CUT_ADC;          // cut at or below (hot NTC reads low)
static uint16_t therm_release_adc = THERM_RELEASE_ADC;  // release at or above
static uint16_t therm_adc[N_MUSCLES];
static uint32_t adc_next_ms;

// ===========================================================================
// Relays
// ===========================================================================

static void relays_write(uint8_t mask) {
  uint8_t bits = 0;
  if (mask & 1) bits |= _BV(RELAY0_BIT);
  if (mask & 2) bits |= _BV(RELAY1_BIT);
  if (mask & 4) bits |= _BV(RELAY2_BIT);
  // Read-modify-write of the port shared with the WDT ISR: keep it atomic.
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
    RELAY_PORT = (uint8_t)((RELAY_PORT & ~RELAY_PORT_MASK) | bits);
  }
}

// What the pins really are, read back from the PIN register (not our belief).
static uint8_t relays_read(void) {
  uint8_t p = RELAY_PINREG;
  uint8_t m = 0;
  if (p & _BV(RELAY0_BIT)) m |= 1;
  if (p & _BV(RELAY1_BIT)) m |= 2;
  if (p & _BV(RELAY2_BIT)) m |= 4;
  return m;
}

static bool muscle_blocked(const Muscle &m) {
  return m.locked || m.bucket_trip || m.overtemp || m.therm_open;
}

static void muscle_clear_command(Muscle &m) {
  m.mode = MODE_OFF;
  m.duty = 0;
}

static void all_off(void) {
  for (uint8_t k = 0; k < N_MUSCLES; k++) {
    muscle_clear_command(mus[k]);
    mus[k].on = false;
  }
  relays_write(0);
}

// Evaluate every muscle's output from its command, the duty window and the
// safety state, account on-time, and write the pins. Called every loop pass
// and right after every command (so the pins have switched before the ACK).
static void muscles_update(uint32_t now) {
  uint32_t dt32 = now - mus_last_update;
  mus_last_update = now;
  int32_t dt = dt32 > 1000UL ? 1000L : (int32_t)dt32;
  uint16_t win_pos = (uint16_t)(now % DUTY_WINDOW_MS);
  uint8_t mask = 0;

  for (uint8_t k = 0; k < N_MUSCLES; k++) {
    Muscle &m = mus[k];

    // Sustained-duty bucket, integrated over the state of the last dt.
    if (m.on) {
      m.bucket += dt;
    } else {
      m.bucket -= DUTY_BUCKET_DRAIN * dt;
      if (m.bucket < 0) m.bucket = 0;
    }
    if (m.bucket_trip && m.bucket == 0) m.bucket_trip = false;
    if (m.locked && (int32_t)(now - m.lock_until) >= 0) m.locked = false;

    bool want = (m.mode == MODE_DIRECT) ||
                (m.mode == MODE_DUTY && win_pos < m.duty);

    if (want && m.on) {
      if (now - m.on_since >= ONTIME_CAP_MS) {
        m.locked = true;
        m.lock_until = now + LOCKOUT_MS;
        muscle_clear_command(m);
        latched_faults |= FAULT_SAFETY_TRIP;
        want = false;
      } else if (m.bucket >= DUTY_BUCKET_CAP_MS) {
        m.bucket_trip = true;
        muscle_clear_command(m);
        latched_faults |= FAULT_SAFETY_TRIP;
        want = false;
      }
    }
    if (muscle_blocked(m)) want = false;

    if (want && !m.on) m.on_since = now;
    m.on = want;
    if (want) mask |= (uint8_t)(1u << k);
  }
  relays_write(mask);
}

// ===========================================================================
// Frames out
// ===========================================================================

static inline uint16_t crc_update(uint16_t crc, uint8_t b) {
  return _crc_xmodem_update(crc, b);  // poly 0x1021, MSB first
}

static uint8_t tx_buf[FRAME_MAX_LEN];

static inline void put_u16(uint8_t *p, uint16_t v) {
  p[0] = (uint8_t)v;
  p[1] = (uint8_t)(v >> 8);
}
static inline void put_u32(uint8_t *p, uint32_t v) {
  put_u16(p, (uint16_t)v);
  put_u16(p + 2, (uint16_t)(v >> 16));
}

// Builds a frame around tx_buf[FRAME_HEADER_LEN..] (the caller has written the
// payload there) and sends it. Droppable frames (telemetry) are skipped rather
// than blocking the loop when the TX buffer is too full.
static bool send_frame(uint8_t type, uint8_t seq, uint8_t len, bool droppable) {
  tx_buf[0] = FRAME_SYNC0;
  tx_buf[1] = FRAME_SYNC1;
  tx_buf[2] = PROTOCOL_VERSION;
  tx_buf[3] = type;
  tx_buf[4] = seq;
  tx_buf[5] = len;
  uint16_t crc = 0xFFFF;
  for (uint8_t i = 2; i < FRAME_HEADER_LEN + len; i++) crc = crc_update(crc, tx_buf[i]);
  uint8_t total = FRAME_HEADER_LEN + len + FRAME_CRC_LEN;
  put_u16(tx_buf + FRAME_HEADER_LEN + len, crc);
  if (droppable && Serial.availableForWrite() < total) {
    latched_faults |= FAULT_TX_OVERFLOW;
    return false;
  }
  Serial.write(tx_buf, total);
  return true;
}

static void send_ack(uint8_t cmd, uint8_t seq, uint8_t info) {
  tx_buf[FRAME_HEADER_LEN + 0] = cmd;
  tx_buf[FRAME_HEADER_LEN + 1] = info;
  send_frame(MSG_ACK, seq, 2, false);
}

static void send_nak(uint8_t cmd, uint8_t seq, uint8_t err) {
  tx_buf[FRAME_HEADER_LEN + 0] = cmd;
  tx_buf[FRAME_HEADER_LEN + 1] = err;
  send_frame(MSG_NAK, seq, 2, false);
}

static void send_boot(void) {
  uint8_t *p = tx_buf + FRAME_HEADER_LEN;
  p[0] = PROTOCOL_VERSION;
  p[1] = FW_VERSION_MAJOR;
  p[2] = FW_VERSION_MINOR;
  p[3] = FW_VERSION_PATCH;
  p[4] = boot_mcusr;
  p[5] = (latched_faults & FAULT_WDT_RESET) ? 1 : 0;
  put_u16(p + 6, nv_wdt_trips);
  send_frame(MSG_BOOT, tx_seq++, 8, false);
}

static void send_hello_reply(uint8_t seq) {
  uint8_t *p = tx_buf + FRAME_HEADER_LEN;
  p[0] = PROTOCOL_VERSION;
  p[1] = FW_VERSION_MAJOR;
  p[2] = FW_VERSION_MINOR;
  p[3] = FW_VERSION_PATCH;
  p[4] = RELAY0_ARDUINO_PIN;
  p[5] = RELAY1_ARDUINO_PIN;
  p[6] = RELAY2_ARDUINO_PIN;
  p[7] = therm_mask;
  put_u16(p + 8, DUTY_WINDOW_MS);
  put_u16(p + 10, DUTY_MAX_PERMILLE);
  put_u16(p + 12, HEARTBEAT_TIMEOUT_MS);
  put_u16(p + 14, ONTIME_CAP_MS);
  put_u16(p + 16, LOCKOUT_MS);
  put_u16(p + 18, DUTY_BUCKET_CAP_MS);
  p[20] = DUTY_BUCKET_DRAIN;
  p[21] = STREAM_MAX_HZ;
  p[22] = (uint8_t)(1000UL / IMU_READ_PERIOD_MS);
  p[23] = IMU_ACCEL_CONFIG_VAL;
  p[24] = IMU_GYRO_CONFIG_VAL;
  p[25] = IMU_CONFIG_VAL;
  put_u16(p + 26, therm_cut_adc);
  put_u16(p + 28, therm_release_adc);
  put_u16(p + 30, THERM_OPEN_ADC);
  p[32] = boot_mcusr;
  send_frame(MSG_HELLO_REPLY, seq, 33, false);
}

static uint16_t live_faults(void) {
  uint16_t f = latched_faults;
  if (!imu_ok) f |= imu_fault;
  for (uint8_t k = 0; k < N_MUSCLES; k++) {
    if (mus[k].locked) f |= FAULT_ONTIME_LOCKOUT;
    if (mus[k].bucket_trip) f |= FAULT_DUTY_LIMIT;
    if (mus[k].overtemp) f |= FAULT_OVERTEMP;
    if (mus[k].therm_open) f |= FAULT_THERM_SENSOR;
  }
  return f;
}

#define TELEMETRY_LEN 45

static bool send_telemetry(uint8_t type, uint8_t seq, bool droppable) {
  uint8_t *p = tx_buf + FRAME_HEADER_LEN;
  uint8_t blocked = 0, modes = 0;
  for (uint8_t k = 0; k < N_MUSCLES; k++) {
    if (muscle_blocked(mus[k])) blocked |= (uint8_t)(1u << k);
    modes |= (uint8_t)(mus[k].mode << (2 * k));
  }
  put_u16(p + 0, telem_seq);
  put_u32(p + 2, millis());
  p[6] = relays_read();
  p[7] = blocked;
  p[8] = modes;
  p[9] = stream_hz;
  for (uint8_t k = 0; k < N_MUSCLES; k++) {
    uint16_t d = mus[k].mode == MODE_DIRECT ? 1000 : mus[k].mode == MODE_DUTY ? mus[k].duty : 0;
    put_u16(p + 10 + 2 * k, d);
  }
  for (uint8_t i = 0; i < 7; i++) put_u16(p + 16 + 2 * i, (uint16_t)imu_raw[i]);
  for (uint8_t k = 0; k < N_MUSCLES; k++) put_u16(p + 30 + 2 * k, therm_adc[k]);
  put_u16(p + 36, live_faults());
  put_u16(p + 38, bad_frames);
  put_u16(p + 40, nv_wdt_trips);
  put_u16(p + 42, imu_errors);
  p[44] = therm_mask;
  bool sent = send_frame(type, seq, TELEMETRY_LEN, droppable);
  if (sent) telem_seq++;
  return sent;
}

// ===========================================================================
// Frames in
// ===========================================================================

static inline uint16_t get_u16(const uint8_t *p) {
  return (uint16_t)p[0] | ((uint16_t)p[1] << 8);
}

static void count_bad_frame(void) {
  if (bad_frames != 0xFFFF) bad_frames++;
}

// Rejects a CRC-valid frame: counted as bad, never acted on, never a heartbeat.
// Frames with an MCU->host type are not answered: a looped-back line would
// otherwise ping-pong NAKs forever.
static void reject(uint8_t type, uint8_t seq, uint8_t err) {
  count_bad_frame();
  if (type < 0x80) send_nak(type, seq, err);
}

static void handle_frame(uint8_t ver, uint8_t type, uint8_t seq, const uint8_t *pl,
                         uint8_t len, uint32_t now) {
  if (ver != PROTOCOL_VERSION) {
    reject(type, seq, ERR_BAD_VERSION);
    return;
  }
  // Expected payload length per type (0xFF = unknown type).
  uint8_t want_len;
  switch (type) {
    case MSG_HELLO: case MSG_STOP: case MSG_HEARTBEAT:
    case MSG_CLEAR_FAULTS: case MSG_GET_STATUS:
      want_len = 0; break;
    case MSG_SET_RELAYS: want_len = 2; break;
    case MSG_SET_DUTY: want_len = 6; break;
    case MSG_STREAM: want_len = 1; break;
    // CONFIG: the mask alone (default cut) or mask + cut + release thresholds.
    case MSG_CONFIG: want_len = (len == 5) ? 5 : 1; break;
    case MSG_WDT_TEST: want_len = 4; break;
    default: want_len = 0xFF; break;
  }
  if (want_len == 0xFF) {
    reject(type, seq, ERR_UNKNOWN_TYPE);
    return;
  }
  if (len != want_len) {
    reject(type, seq, ERR_BAD_LENGTH);
    return;
  }

  // Value checks before anything is changed: a rejected command has no effect.
  switch (type) {
    case MSG_SET_RELAYS:
      if ((pl[0] & 0xF8u) != 0 || (uint8_t)(pl[0] ^ 0xFFu) != pl[1]) {
        reject(type, seq, ERR_BAD_VALUE);
        return;
      }
      break;
    case MSG_SET_DUTY:
      for (uint8_t k = 0; k < N_MUSCLES; k++)
        if (get_u16(pl + 2 * k) > 1000) {
          reject(type, seq, ERR_BAD_VALUE);
          return;
        }
      break;
    case MSG_STREAM:
      if (pl[0] > STREAM_MAX_HZ) {
        reject(type, seq, ERR_BAD_VALUE);
        return;
      }
      break;
    case MSG_CONFIG:
      if ((pl[0] & 0xF8u) != 0) {
        reject(type, seq, ERR_BAD_VALUE);
        return;
      }
      if (len == 5) {
        // Never hotter than the firmware's own maximum, a real hysteresis, and a
        // release below the open-sensor reading (else a cut would never end).
        uint16_t cut = get_u16(pl + 1), rel = get_u16(pl + 3);
        if (cut < THERM_CUT_ADC_MIN || cut >= THERM_OPEN_ADC || rel >= THERM_OPEN_ADC ||
            rel < cut + THERM_HYSTERESIS_ADC_MIN) {
          reject(type, seq, ERR_BAD_VALUE);
          return;
        }
      }
      break;
    case MSG_WDT_TEST:
      if (pl[0] != WDT_TEST_MAGIC0 || pl[1] != WDT_TEST_MAGIC1 ||
          pl[2] != WDT_TEST_MAGIC2 || pl[3] != WDT_TEST_MAGIC3) {
        reject(type, seq, ERR_BAD_VALUE);
        return;
      }
      break;
    default:
      break;
  }

  // A valid frame: it feeds the heartbeat and clears the heartbeat fault.
  last_valid_ms = now;
  link_armed = true;
  latched_faults &= (uint16_t)~FAULT_HEARTBEAT_LOST;

  uint8_t info = 0;
  switch (type) {
    case MSG_HELLO:
      send_hello_reply(seq);
      return;
    case MSG_GET_STATUS:
      send_telemetry(MSG_STATUS, seq, false);
      return;
    case MSG_SET_RELAYS:
      for (uint8_t k = 0; k < N_MUSCLES; k++) {
        Muscle &m = mus[k];
        if (pl[0] & (1u << k)) {
          if (muscle_blocked(m)) {
            info |= (uint8_t)(1u << k);
            muscle_clear_command(m);
          } else {
            m.mode = MODE_DIRECT;
            m.duty = 1000;
          }
        } else {
          muscle_clear_command(m);
        }
      }
      break;
    case MSG_SET_DUTY:
      for (uint8_t k = 0; k < N_MUSCLES; k++) {
        Muscle &m = mus[k];
        uint16_t d = get_u16(pl + 2 * k);
        if (d > DUTY_MAX_PERMILLE) {
          d = DUTY_MAX_PERMILLE;
          info |= (uint8_t)(0x10u << k);
        }
        if (d == 0) {
          muscle_clear_command(m);
        } else if (muscle_blocked(m)) {
          info |= (uint8_t)(1u << k);
          muscle_clear_command(m);
        } else {
          m.mode = MODE_DUTY;
          m.duty = d;
        }
      }
      break;
    case MSG_STREAM:
      stream_hz = pl[0];
      stream_next_ms = now;
      break;
    case MSG_STOP:
      all_off();
      stream_hz = 0;
      break;
    case MSG_HEARTBEAT:
      break;
    case MSG_CONFIG:
      therm_mask = pl[0];
      therm_cut_adc = (len == 5) ? get_u16(pl + 1) : THERM_CUT_ADC;
      therm_release_adc = (len == 5) ? get_u16(pl + 3) : THERM_RELEASE_ADC;
      for (uint8_t k = 0; k < N_MUSCLES; k++) {
        if (!(therm_mask & (1u << k))) {
          mus[k].overtemp = mus[k].therm_open = false;
          mus[k].hot_count = mus[k].open_count = 0;
        }
      }
      break;
    case MSG_CLEAR_FAULTS:
      latched_faults = 0;
      break;
    case MSG_WDT_TEST:
      // Watchdog self-test: acknowledge, then hang with interrupts enabled
      // like a stuck main loop would. The outputs are deliberately left as
      // they are, so the test also proves that the WDT interrupt switches
      // them off (one WDT period, ~256 ms, later) before the reset follows.
      send_ack(type, seq, 0);
      Serial.flush();
      for (;;) {
      }
  }
  muscles_update(now);
  send_ack(type, seq, info);
}

static inline void rx_shift(uint8_t n) {
  if (n >= rx_len) {
    rx_len = 0;
    return;
  }
  memmove(rx_buf, rx_buf + n, rx_len - n);
  rx_len -= n;
}

// Parses as many complete frames as the buffer holds. On any framing error
// only the first byte is dropped and the rest re-scanned, so a real frame that
// started inside garbage or inside a truncated frame is still found.
static void rx_process(uint32_t now) {
  for (;;) {
    uint8_t i = 0;
    while (i < rx_len && rx_buf[i] != FRAME_SYNC0) i++;
    rx_shift(i);
    if (rx_len < 2) return;
    if (rx_buf[1] != FRAME_SYNC1) {
      rx_shift(1);
      continue;
    }
    if (rx_len < FRAME_HEADER_LEN) return;
    uint8_t plen = rx_buf[5];
    if (plen > FRAME_MAX_PAYLOAD) {
      count_bad_frame();
      rx_shift(1);
      continue;
    }
    uint8_t total = FRAME_HEADER_LEN + plen + FRAME_CRC_LEN;
    if (rx_len < total) return;
    uint16_t crc = 0xFFFF;
    for (uint8_t j = 2; j < FRAME_HEADER_LEN + plen; j++) crc = crc_update(crc, rx_buf[j]);
    if (crc != get_u16(rx_buf + FRAME_HEADER_LEN + plen)) {
      count_bad_frame();
      rx_shift(1);
      continue;
    }
    // Copy out: handlers send replies and the WDT test never returns, but the
    // payload must not alias rx_buf while we shift it afterwards.
    uint8_t payload[FRAME_MAX_PAYLOAD];
    memcpy(payload, rx_buf + FRAME_HEADER_LEN, plen);
    uint8_t ver = rx_buf[2], type = rx_buf[3], seq = rx_buf[4];
    rx_shift(total);
    handle_frame(ver, type, seq, payload, plen, now);
  }
}

static void link_poll(uint32_t now) {
  uint8_t budget = 32;  // bytes per loop pass: keep the loop period bounded
  while (budget-- && Serial.available() > 0) {
    rx_buf[rx_len++] = (uint8_t)Serial.read();
    rx_last_byte_ms = now;
    rx_process(now);
  }
  // A partial frame with no new byte for a while is a truncated frame.
  while (rx_len > 0 && now - rx_last_byte_ms > FRAME_STALE_MS) {
    count_bad_frame();
    rx_shift(1);
    rx_process(now);
  }
  // Host silence: everything off; the commands are forgotten, so the relays
  // only come back on when the host commands them again.
  if (link_armed && now - last_valid_ms > HEARTBEAT_TIMEOUT_MS) {
    link_armed = false;
    bool any = false;
    for (uint8_t k = 0; k < N_MUSCLES; k++) any |= mus[k].mode != MODE_OFF;
    all_off();
    latched_faults |= FAULT_HEARTBEAT_LOST;
    if (any) latched_faults |= FAULT_SAFETY_TRIP;
  }
}

// ===========================================================================
// MPU6050 (interrupt-driven Wire library, bounded by Wire's timeout)
// ===========================================================================

#define MPU_REG_SMPLRT_DIV 0x19
#define MPU_REG_CONFIG 0x1A
#define MPU_REG_GYRO_CONFIG 0x1B
#define MPU_REG_ACCEL_CONFIG 0x1C
#define MPU_REG_ACCEL_XOUT_H 0x3B
#define MPU_REG_PWR_MGMT_1 0x6B
#define MPU_REG_WHO_AM_I 0x75

// Maps an endTransmission() status to a fault bit (0 = fine).
static uint16_t i2c_status_fault(uint8_t e) {
  if (Wire.getWireTimeoutFlag()) {
    Wire.clearWireTimeoutFlag();
    return FAULT_IMU_READ;
  }
  if (e == 0) return 0;
  // 2 = address NACK (nobody home). 3 = data NACK: counted as "no ACK" too,
  // because a device that stops acknowledging is as good as gone -- and
  // simavr 1.6 reports an address NACK as a data NACK (status 0x30, not 0x20).
  if (e == 2 || e == 3) return FAULT_IMU_MISSING;
  return FAULT_IMU_READ;
}

static uint16_t imu_write_reg(uint8_t reg, uint8_t val) {
  Wire.beginTransmission(IMU_ADDR);
  Wire.write(reg);
  Wire.write(val);
  return i2c_status_fault(Wire.endTransmission());
}

// Reads n bytes starting at reg (register pointer write, repeated start, read).
static uint16_t imu_read_regs(uint8_t reg, uint8_t *dst, uint8_t n) {
  Wire.beginTransmission(IMU_ADDR);
  Wire.write(reg);
  uint16_t f = i2c_status_fault(Wire.endTransmission(false));
  if (f) return f;
  uint8_t got = Wire.requestFrom((uint8_t)IMU_ADDR, n);
  if (Wire.getWireTimeoutFlag()) {
    Wire.clearWireTimeoutFlag();
    return FAULT_IMU_READ;
  }
  if (got != n) {
    while (Wire.available()) Wire.read();
    return FAULT_IMU_READ;
  }
  for (uint8_t i = 0; i < n; i++) dst[i] = (uint8_t)Wire.read();
  return 0;
}

static uint16_t imu_probe_and_init(void) {
  uint8_t id;
  uint16_t f = imu_read_regs(MPU_REG_WHO_AM_I, &id, 1);
  if (f) return f;
  if (id != IMU_WHO_AM_I_VALUE) return FAULT_IMU_BAD_ID;
  if ((f = imu_write_reg(MPU_REG_PWR_MGMT_1, IMU_PWR_MGMT_1_VAL))) return f;
  if ((f = imu_write_reg(MPU_REG_SMPLRT_DIV, IMU_SMPLRT_DIV_VAL))) return f;
  if ((f = imu_write_reg(MPU_REG_CONFIG, IMU_CONFIG_VAL))) return f;
  if ((f = imu_write_reg(MPU_REG_GYRO_CONFIG, IMU_GYRO_CONFIG_VAL))) return f;
  if ((f = imu_write_reg(MPU_REG_ACCEL_CONFIG, IMU_ACCEL_CONFIG_VAL))) return f;
  return 0;
}

// Periodic health check: an IMU that browned out (relay switching at 8 A)
// comes back asleep with default ranges and would silently report zeros.
static uint16_t imu_health_check(void) {
  uint8_t v;
  uint16_t f = imu_read_regs(MPU_REG_WHO_AM_I, &v, 1);
  if (f) return f;
  if (v != IMU_WHO_AM_I_VALUE) return FAULT_IMU_BAD_ID;
  if ((f = imu_read_regs(MPU_REG_PWR_MGMT_1, &v, 1))) return f;
  if (v != IMU_PWR_MGMT_1_VAL) return FAULT_IMU_READ;
  return 0;
}

static void imu_set_fault(uint16_t f, uint32_t now) {
  imu_ok = false;
  imu_fault = f;
  if (imu_errors != 0xFFFF) imu_errors++;
  memset(imu_raw, 0, sizeof(imu_raw));  // never report stale data as fresh
  imu_next_ms = now + IMU_RETRY_PERIOD_MS;
}

static void imu_task(uint32_t now) {
  if ((int32_t)(now - imu_next_ms) < 0) return;
  if (!imu_ok) {
    uint16_t f = imu_probe_and_init();
    if (f) {
      imu_set_fault(f, now);
    } else {
      imu_ok = true;
      imu_fault = 0;
      imu_next_ms = now;
      imu_check_ms = now + IMU_RETRY_PERIOD_MS;
    }
    return;
  }
  if ((int32_t)(now - imu_check_ms) >= 0) {
    imu_check_ms = now + IMU_RETRY_PERIOD_MS;
    uint16_t f = imu_health_check();
    if (f) {
      imu_set_fault(f, now);
      return;
    }
  }
  uint8_t b[14];
  uint16_t f = imu_read_regs(MPU_REG_ACCEL_XOUT_H, b, 14);
  if (f) {
    imu_set_fault(f, now);
    return;
  }
  for (uint8_t i = 0; i < 7; i++) imu_raw[i] = (int16_t)(((uint16_t)b[2 * i] << 8) | b[2 * i + 1]);
  imu_next_ms += IMU_READ_PERIOD_MS;
  if ((int32_t)(now - imu_next_ms) > (int32_t)IMU_READ_PERIOD_MS) imu_next_ms = now;  // fell behind
}

// ===========================================================================
// Thermistors
// ===========================================================================

static void therm_task(uint32_t now) {
  if ((int32_t)(now - adc_next_ms) < 0) return;
  adc_next_ms = now + ADC_PERIOD_MS;
  for (uint8_t k = 0; k < N_MUSCLES; k++) {
    uint16_t v = (uint16_t)analogRead(A0 + k);
    therm_adc[k] = v;
    if (!(therm_mask & (1u << k))) continue;
    Muscle &m = mus[k];

    if (v >= THERM_OPEN_ADC) {
      if (m.open_count < THERM_CONFIRM_SAMPLES) m.open_count++;
    } else {
      m.open_count = 0;
    }
    bool open = m.open_count >= THERM_CONFIRM_SAMPLES;
    if (open && !m.therm_open && m.mode != MODE_OFF) latched_faults |= FAULT_SAFETY_TRIP;
    if (open && !m.therm_open) muscle_clear_command(m);
    m.therm_open = open;

    if (v <= therm_cut_adc) {
      if (m.hot_count < THERM_CONFIRM_SAMPLES) m.hot_count++;
    } else {
      m.hot_count = 0;
    }
    if (!m.overtemp && m.hot_count >= THERM_CONFIRM_SAMPLES) {
      m.overtemp = true;
      if (m.mode != MODE_OFF) latched_faults |= FAULT_SAFETY_TRIP;
      muscle_clear_command(m);
    } else if (m.overtemp && v >= therm_release_adc) {
      m.overtemp = false;
    }
  }
}

// ===========================================================================
// Arduino entry points
// ===========================================================================

void setup() {
  // Relays are already off (early_init). Sort out what kind of reset this was.
  bool cold = (boot_mcusr & _BV(PORF)) || nv_magic != NV_MAGIC;
  if (cold) {
    nv_magic = NV_MAGIC;
    nv_wdt_trips = 0;
    nv_wdt_flag = 0;
  }
  bool wdt_caused = (boot_mcusr & _BV(WDRF)) || nv_wdt_flag == NV_WDT_FLAG_MAGIC;
  // A watchdog reset whose ISR never ran (interrupts were off) is counted here.
  if ((boot_mcusr & _BV(WDRF)) && nv_wdt_flag != NV_WDT_FLAG_MAGIC) nv_wdt_trips++;
  nv_wdt_flag = 0;
  if (wdt_caused) latched_faults |= FAULT_WDT_RESET;

  Serial.begin(SERIAL_BAUD);
  Wire.begin();
  Wire.setClock(I2C_CLOCK_HZ);
  Wire.setWireTimeout(I2C_TIMEOUT_US, true);

  uint32_t now = millis();
  mus_last_update = now;
  imu_next_ms = now;
  adc_next_ms = now;
  rx_last_byte_ms = now;

  hw_watchdog_start();
  send_boot();
}

void loop() {
  wdt_reset();
  uint32_t now = millis();
  link_poll(now);
  imu_task(now);
  therm_task(now);
  now = millis();
  muscles_update(now);

  if (stream_hz && (int32_t)(now - stream_next_ms) >= 0) {
    send_telemetry(MSG_TELEMETRY, tx_seq++, true);
    stream_next_ms += 1000U / stream_hz;
    // Never try to catch up a backlog: resynchronise after a stall.
    if ((int32_t)(now - stream_next_ms) > 100) stream_next_ms = now;
  }
}
