/*
 * neck_hil -- simavr hardware-in-the-loop harness for the neck firmware.
 *
 * Runs the real firmware ELF on a simulated ATmega328P (16 MHz) and wires it to
 * a fake world:
 *   - UART0 <-> a pseudo-terminal (the host opens it with pyserial like a real
 *     UNO's /dev/ttyACM0);
 *   - an MPU6050 I2C slave at 0x68 (register file, auto-increment pointer,
 *     WHO_AM_I, sleep bit), which can be made absent (address NACK);
 *   - analog inputs A0..A7 (raw ADC counts);
 *   - relay pins D5, D6, D7 (PD5..PD7) reported on every change.
 * It is driven by a line-based text protocol on stdin/stdout (README.md).
 *
 * Everything runs in one thread: simavr is not thread-safe, and pacing plus
 * I/O polling between 1 ms slices of simulated time is plenty for 115200 baud.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <avr_adc.h>
#include <avr_ioport.h>
#include <avr_twi.h>
#include <avr_uart.h>
#include <sim_avr.h>
#include <sim_elf.h>
#include <sim_irq.h>

/* ---- ATmega328P register addresses (data space) ---- */
#define REG_PORTD 0x2B
#define REG_SPL 0x5D
#define REG_SPH 0x5E
#define REG_UCSR0B 0xC1
#define BIT_RXEN0 4
#define RELAY_FIRST_BIT 5 /* PD5, PD6, PD7 = muscles 0, 1, 2 */
#define N_RELAYS 3

#define MPU_ADDR 0x68

/* ---- small byte queue ---- */
typedef struct {
	uint8_t *buf;
	size_t cap, head, len;
} bq_t;

static void bq_init(bq_t *q, size_t cap) {
	q->buf = malloc(cap);
	q->cap = cap;
	q->head = q->len = 0;
	if (!q->buf) {
		perror("malloc");
		exit(2);
	}
}
/* Returns the number of bytes that did not fit (dropped). */
static size_t bq_push(bq_t *q, const uint8_t *d, size_t n) {
	size_t dropped = 0;
	if (n > q->cap - q->len) {
		dropped = n - (q->cap - q->len);
		n = q->cap - q->len;
	}
	for (size_t i = 0; i < n; i++) q->buf[(q->head + q->len + i) % q->cap] = d[i];
	q->len += n;
	return dropped;
}
static int bq_pop(bq_t *q) {
	if (!q->len) return -1;
	uint8_t v = q->buf[q->head];
	q->head = (q->head + 1) % q->cap;
	q->len--;
	return v;
}
/* Contiguous readable span at the head. */
static size_t bq_span(bq_t *q, uint8_t **p) {
	*p = q->buf + q->head;
	size_t s = q->cap - q->head;
	return s < q->len ? s : q->len;
}
static void bq_drop(bq_t *q, size_t n) {
	q->head = (q->head + n) % q->cap;
	q->len -= n;
}

/* ---- global state ---- */
static avr_t *avr;
static int verbose;
static double speed = 1.0;   /* 1 = real time, 0 = unpaced */
static int running;          /* MCU released by RUN */
static int quit;
static int mcu_dead;         /* crashed or stopped */

static int pty_master = -1, pty_slave_keep = -1;
static char pty_name[128];

static bq_t uart_rxq; /* host -> MCU, waiting for room in simavr's UART FIFO */
static bq_t uart_txq; /* MCU -> host, waiting for the pty to accept it */
static int uart_xoff; /* simavr's 64-byte RX FIFO is full */
static avr_irq_t *uart_in_irq;
static uint64_t stat_rx_bytes, stat_tx_bytes, stat_tx_dropped, stat_rx_dropped, stat_lag_resync;

static avr_irq_t *twi_in_irq;
static avr_irq_t *adc_irq_base;

static uint8_t relay_reported; /* bit k = last reported state of muscle k */
static uint16_t sp_min = 0xFFFF; /* lowest stack pointer seen: peak stack use */
static uint64_t resets_seen;

/* Periodic injections (e.g. heartbeats) on simulated time, a few slots. */
#define N_INJECT 4
static struct {
	uint8_t bytes[256];
	size_t len;
	uint64_t period_us, next_us;
} inject[N_INJECT];

/* Pacing anchor: sim time sim_ref_us corresponds to wall time wall_ref_ns. */
static uint64_t sim_ref_us;
static int64_t wall_ref_ns;

/* ---- MPU6050 model ---- */
static struct {
	uint8_t reg[128];
	uint8_t ptr;
	int selected;      /* addressed since the last START */
	int expect_ptr;    /* next written byte is the register pointer */
	int absent;        /* do not ACK the address at all */
	uint8_t whoami;
	int16_t sensor[7]; /* ax ay az temp gx gy gz, raw register values */
	uint64_t reads, writes;
} mpu;

/* IMU_AT: samples stamped with the simulated time from which they hold. A plant in another
 * process computes ahead of the MCU (relays as they are) and queues its samples; the firmware
 * reads the one due at its own clock however late that process is scheduled, where serving only
 * the latest value would hand it a tilt as old as the plant's lateness. */
#define IMU_QUEUE 256
static uint64_t sim_us(void);
static struct {
	uint64_t t_us;
	int16_t v[6]; /* ax ay az gx gy gz */
} imu_q[IMU_QUEUE];
static int imu_q_len;
static int imu_q_used;             /* a plant queues samples: their age is tracked */
static uint64_t imu_q_served_t_us; /* time stamp of the sample the registers hold */
static uint64_t stat_imu_age_max_us; /* oldest sample a burst read was served (simulated us) */

/* The samples due at `now` leave the queue; the last of them becomes the registers. */
static void imu_queue_take(uint64_t now) {
	int k = 0;
	while (k < imu_q_len && imu_q[k].t_us <= now) k++;
	if (!k) return;
	imu_q_served_t_us = imu_q[k - 1].t_us;
	const int16_t *v = imu_q[k - 1].v;
	mpu.sensor[0] = v[0];
	mpu.sensor[1] = v[1];
	mpu.sensor[2] = v[2];
	mpu.sensor[4] = v[3];
	mpu.sensor[5] = v[4];
	mpu.sensor[6] = v[5];
	memmove(imu_q, imu_q + k, (size_t)(imu_q_len - k) * sizeof imu_q[0]);
	imu_q_len -= k;
}

/* A burst read starts: serve the sample due now, and count how old it is. */
static void imu_burst_start(uint64_t now) {
	imu_queue_take(now);
	if (imu_q_used && now - imu_q_served_t_us > stat_imu_age_max_us)
		stat_imu_age_max_us = now - imu_q_served_t_us;
}

static void mpu_defaults(void) {
	memset(mpu.reg, 0, sizeof(mpu.reg));
	mpu.reg[0x6B] = 0x40; /* PWR_MGMT_1: SLEEP set at power-up */
}

static uint8_t mpu_read_reg(uint8_t r) {
	r &= 0x7F;
	if (r == 0x75) return mpu.whoami;
	if (r == 0x3B) imu_burst_start(sim_us()); /* one sample, whole, per burst */
	if (r >= 0x3B && r <= 0x48) {
		/* Asleep: the data registers are not updated (we report zeros). */
		if (mpu.reg[0x6B] & 0x40) return 0;
		int i = (r - 0x3B) / 2;
		uint16_t v = (uint16_t)mpu.sensor[i];
		return (r - 0x3B) % 2 == 0 ? (uint8_t)(v >> 8) : (uint8_t)v;
	}
	return mpu.reg[r];
}

static void mpu_write_reg(uint8_t r, uint8_t v) {
	r &= 0x7F;
	mpu.writes++;
	if (verbose) fprintf(stderr, "neck_hil: MPU write reg 0x%02X = 0x%02X\n", r, v);
	if (r == 0x6B && (v & 0x80)) { /* DEVICE_RESET */
		mpu_defaults();
		return;
	}
	if (r == 0x75 || (r >= 0x3B && r <= 0x48)) return; /* read-only */
	mpu.reg[r] = v;
}

/* Bus traffic from the AVR's TWI master. simavr expects the slave to answer
 * synchronously by raising TWI_IRQ_INPUT (ACK bit, or the data byte on a read);
 * no answer means NACK. */
static void twi_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
	(void)irq;
	(void)param;
	avr_twi_msg_irq_t m;
	m.u.v = value;
	if (m.u.twi.msg & TWI_COND_STOP) mpu.selected = 0;
	if (m.u.twi.msg & TWI_COND_START) {
		mpu.selected = 0;
		if (!mpu.absent && (m.u.twi.addr >> 1) == MPU_ADDR) {
			mpu.selected = 1;
			mpu.expect_ptr = !(m.u.twi.addr & 1);
			avr_raise_irq(twi_in_irq, avr_twi_irq_msg(TWI_COND_ACK, m.u.twi.addr, 1));
		}
	}
	if (!mpu.selected) return;
	if (m.u.twi.msg & TWI_COND_WRITE) {
		avr_raise_irq(twi_in_irq, avr_twi_irq_msg(TWI_COND_ACK, m.u.twi.addr, 1));
		if (mpu.expect_ptr) {
			mpu.ptr = m.u.twi.data & 0x7F;
			mpu.expect_ptr = 0;
		} else {
			mpu_write_reg(mpu.ptr, m.u.twi.data);
			mpu.ptr = (mpu.ptr + 1) & 0x7F;
		}
	}
	if (m.u.twi.msg & TWI_COND_READ) {
		uint8_t d = mpu_read_reg(mpu.ptr);
		mpu.ptr = (mpu.ptr + 1) & 0x7F;
		mpu.reads++;
		avr_raise_irq(twi_in_irq, avr_twi_irq_msg(TWI_COND_READ, m.u.twi.addr, d));
	}
}

/* ---- output helpers ---- */
static void out(const char *fmt, ...) {
	va_list ap;
	va_start(ap, fmt);
	vfprintf(stdout, fmt, ap);
	va_end(ap);
	fputc('\n', stdout);
	if (fflush(stdout) != 0) quit = 1; /* controller went away */
}

static uint64_t sim_us(void) { return avr ? avr->cycle * 1000000ULL / avr->frequency : 0; }

static int64_t wall_ns(void) {
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static void pace_anchor(void) {
	sim_ref_us = sim_us();
	wall_ref_ns = wall_ns();
}

/* A relay counts as ON whenever its PORT bit is set: driven high, or (DDR=0)
 * the internal pull-up, which some relay boards would also take as "on". This
 * is the conservative reading for safety tests. */
static void check_relays(void) {
	uint8_t now = (avr->data[REG_PORTD] >> RELAY_FIRST_BIT) & 0x07;
	if (now == relay_reported) return;
	uint64_t t = sim_us();
	for (int k = 0; k < N_RELAYS; k++) {
		uint8_t b = 1u << k;
		if ((now ^ relay_reported) & b) out("RELAY %llu %d %d", (unsigned long long)t, k, (now & b) ? 1 : 0);
	}
	relay_reported = now;
}

/* ---- simavr callbacks ---- */
static void uart_out_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
	(void)irq;
	(void)param;
	uint8_t b = (uint8_t)value;
	stat_tx_bytes++;
	stat_tx_dropped += bq_push(&uart_txq, &b, 1);
}
static void uart_xon_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
	(void)irq;
	(void)param;
	if (value) uart_xoff = 0;
}
static void uart_xoff_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
	(void)irq;
	(void)param;
	uart_xoff = value ? 1 : 0;
}

/* simavr's default logger prints to stdout, which is our control channel. */
static void logger(avr_t *a, const int level, const char *fmt, va_list ap) {
	if (a && level > a->log) return;
	vfprintf(stderr, fmt, ap);
}

/* Feed queued host bytes into the UART while its FIFO has room. Bytes wait
 * (rather than being lost) while the firmware has the receiver disabled. */
static void uart_feed(void) {
	if (!(avr->data[REG_UCSR0B] & (1u << BIT_RXEN0))) return;
	while (uart_rxq.len && !uart_xoff) {
		int b = bq_pop(&uart_rxq);
		avr_raise_irq(uart_in_irq, (uint32_t)b);
	}
}

/* ---- command handling ---- */
static int parse_hex(const char *s, uint8_t *dst, size_t max, size_t *n) {
	*n = 0;
	while (*s == ' ') s++;
	size_t len = strlen(s);
	while (len && (s[len - 1] == ' ' || s[len - 1] == '\r')) len--;
	if (len % 2) return -1;
	for (size_t i = 0; i < len; i += 2) {
		unsigned v;
		char tmp[3] = {s[i], s[i + 1], 0};
		char *end;
		v = (unsigned)strtoul(tmp, &end, 16);
		if (*end || *n >= max) return -1;
		dst[(*n)++] = (uint8_t)v;
	}
	return 0;
}

static void set_adc(int ch, long raw) {
	/* simavr converts millivolts: code = mV * 1023 / VREF(5000). Rounding the
	 * millivolts up makes the firmware read back exactly `raw`. */
	uint32_t mv = (uint32_t)((raw * 5000 + 1022) / 1023);
	avr_raise_irq(adc_irq_base + ch, mv);
}

static void handle_line(char *line) {
	size_t L = strlen(line);
	while (L && (line[L - 1] == '\n' || line[L - 1] == '\r' || line[L - 1] == ' ')) line[--L] = 0;
	if (!L) return;
	char cmd[32] = {0};
	int off = 0;
	if (sscanf(line, "%31s %n", cmd, &off) < 1) return;
	const char *args = line + off;

	if (!strcmp(cmd, "RUN")) {
		if (!running) {
			running = 1;
			pace_anchor();
		}
		out("OK RUN");
	} else if (!strcmp(cmd, "QUIT")) {
		out("OK QUIT");
		quit = 1;
	} else if (!strcmp(cmd, "TIME?")) {
		out("TIME %llu", (unsigned long long)sim_us());
	} else if (!strcmp(cmd, "RELAYS?")) {
		uint8_t r = (avr->data[REG_PORTD] >> RELAY_FIRST_BIT) & 0x07;
		out("RELAYS %llu %d %d %d", (unsigned long long)sim_us(), r & 1, (r >> 1) & 1, (r >> 2) & 1);
	} else if (!strcmp(cmd, "IMU")) {
		int v[6];
		if (sscanf(args, "%d %d %d %d %d %d", &v[0], &v[1], &v[2], &v[3], &v[4], &v[5]) != 6) {
			out("ERR IMU needs ax ay az gx gy gz");
			return;
		}
		for (int i = 0; i < 6; i++)
			if (v[i] < -32768 || v[i] > 32767) {
				out("ERR IMU value out of int16 range");
				return;
			}
		mpu.sensor[0] = (int16_t)v[0];
		mpu.sensor[1] = (int16_t)v[1];
		mpu.sensor[2] = (int16_t)v[2];
		mpu.sensor[4] = (int16_t)v[3];
		mpu.sensor[5] = (int16_t)v[4];
		mpu.sensor[6] = (int16_t)v[5];
		out("OK IMU");
	} else if (!strcmp(cmd, "IMU_AT")) {
		/* groups of "t_us ax ay az gx gy gz", t ascending; queued samples at or after the
		 * first t are replaced (the plant recomputed them after a relay edge) */
		const char *p = args;
		int n = 0, off = 0;
		unsigned long long t;
		int v[6];
		int first = 1;
		while (sscanf(p, "%llu %d %d %d %d %d %d %n", &t, &v[0], &v[1], &v[2], &v[3], &v[4], &v[5], &off) == 7) {
			for (int i = 0; i < 6; i++)
				if (v[i] < -32768 || v[i] > 32767) {
					out("ERR IMU_AT value out of int16 range");
					return;
				}
			if (first) {
				while (imu_q_len && imu_q[imu_q_len - 1].t_us >= t) imu_q_len--;
				if (!imu_q_used) imu_q_served_t_us = sim_us(); /* from the plain IMU value */
				imu_q_used = 1;
				first = 0;
			} else if (imu_q_len && t <= imu_q[imu_q_len - 1].t_us) {
				out("ERR IMU_AT times must ascend");
				return;
			}
			if (imu_q_len == IMU_QUEUE) {
				/* nobody read the IMU (unplugged): the due samples become the registers */
				imu_queue_take(sim_us());
			}
			if (imu_q_len == IMU_QUEUE) {
				out("ERR IMU_AT queue full (%d samples ahead of the MCU)", IMU_QUEUE);
				return;
			}
			imu_q[imu_q_len].t_us = t;
			for (int i = 0; i < 6; i++) imu_q[imu_q_len].v[i] = (int16_t)v[i];
			imu_q_len++;
			n++;
			p += off;
		}
		if (!n || *p) {
			out("ERR IMU_AT needs groups of t_us ax ay az gx gy gz");
			return;
		}
		out("OK IMU_AT");
	} else if (!strcmp(cmd, "IMU_TEMP")) {
		int t;
		if (sscanf(args, "%d", &t) != 1 || t < -32768 || t > 32767) {
			out("ERR IMU_TEMP needs an int16");
			return;
		}
		mpu.sensor[3] = (int16_t)t;
		out("OK IMU_TEMP");
	} else if (!strcmp(cmd, "IMU_ABSENT")) {
		int a;
		if (sscanf(args, "%d", &a) != 1) {
			out("ERR IMU_ABSENT needs 0|1");
			return;
		}
		mpu.absent = a != 0;
		if (mpu.absent) mpu.selected = 0;
		else mpu_defaults(); /* plugged back in: powers up asleep */
		out("OK IMU_ABSENT");
	} else if (!strcmp(cmd, "IMU_WHOAMI")) {
		unsigned w;
		if (sscanf(args, "%i", (int *)&w) != 1 || w > 255) {
			out("ERR IMU_WHOAMI needs 0..255");
			return;
		}
		mpu.whoami = (uint8_t)w;
		out("OK IMU_WHOAMI");
	} else if (!strcmp(cmd, "IMUREG?")) {
		int r;
		if (sscanf(args, "%i", &r) != 1 || r < 0 || r > 127) {
			out("ERR IMUREG? needs 0..127");
			return;
		}
		out("IMUREG %d %d", r, mpu_read_reg((uint8_t)r));
	} else if (!strcmp(cmd, "ADC")) {
		int ch;
		long raw;
		if (sscanf(args, "%d %ld", &ch, &raw) != 2 || ch < 0 || ch > 7 || raw < 0 || raw > 1023) {
			out("ERR ADC needs ch 0..7 and value 0..1023");
			return;
		}
		set_adc(ch, raw);
		out("OK ADC");
	} else if (!strcmp(cmd, "SPEED")) {
		double s;
		if (sscanf(args, "%lf", &s) != 1 || s < 0) {
			out("ERR SPEED needs a factor >= 0 (0 = unpaced)");
			return;
		}
		speed = s;
		pace_anchor();
		out("OK SPEED");
	} else if (!strcmp(cmd, "SEND")) {
		uint8_t b[512];
		size_t n;
		if (parse_hex(args, b, sizeof b, &n) < 0) {
			out("ERR SEND needs hex bytes");
			return;
		}
		stat_rx_dropped += bq_push(&uart_rxq, b, n);
		out("OK SEND");
	} else if (!strcmp(cmd, "INJECT")) {
		int slot;
		unsigned long period_ms;
		int o2 = 0;
		if (sscanf(args, "%d %lu %n", &slot, &period_ms, &o2) < 2 || slot < 0 || slot >= N_INJECT) {
			out("ERR INJECT needs slot(0..3) period_ms [hex]");
			return;
		}
		size_t n = 0;
		if (period_ms && parse_hex(args + o2, inject[slot].bytes, sizeof inject[slot].bytes, &n) < 0) {
			out("ERR INJECT needs hex bytes");
			return;
		}
		inject[slot].len = period_ms ? n : 0;
		inject[slot].period_us = period_ms * 1000ULL;
		inject[slot].next_us = sim_us() + inject[slot].period_us;
		out("OK INJECT");
	} else if (!strcmp(cmd, "RESET")) {
		avr_reset(avr);
		mcu_dead = 0;
		check_relays();
		out("OK RESET");
	} else if (!strcmp(cmd, "STATS?")) {
		out("STATS rx=%llu tx=%llu tx_dropped=%llu rx_dropped=%llu resets=%llu lag_resync=%llu "
		    "imu_reads=%llu imu_writes=%llu imu_age_max_us=%llu sp_min=%u",
		    (unsigned long long)stat_rx_bytes, (unsigned long long)stat_tx_bytes,
		    (unsigned long long)stat_tx_dropped, (unsigned long long)stat_rx_dropped,
		    (unsigned long long)resets_seen, (unsigned long long)stat_lag_resync,
		    (unsigned long long)mpu.reads, (unsigned long long)mpu.writes,
		    (unsigned long long)stat_imu_age_max_us, (unsigned)sp_min);
	} else {
		out("ERR unknown command %s", cmd);
	}
}

/* ---- I/O service ---- */
static char ctl_buf[4096];
static size_t ctl_len;

static void read_control(void) {
	ssize_t n = read(STDIN_FILENO, ctl_buf + ctl_len, sizeof ctl_buf - 1 - ctl_len);
	if (n == 0) { /* controller closed stdin: it is gone, so are we */
		quit = 1;
		return;
	}
	if (n < 0) {
		if (errno != EAGAIN && errno != EINTR) quit = 1;
		return;
	}
	ctl_len += (size_t)n;
	ctl_buf[ctl_len] = 0;
	char *start = ctl_buf, *nl;
	while ((nl = memchr(start, '\n', ctl_len - (size_t)(start - ctl_buf)))) {
		*nl = 0;
		handle_line(start);
		start = nl + 1;
	}
	size_t rest = ctl_len - (size_t)(start - ctl_buf);
	memmove(ctl_buf, start, rest);
	ctl_len = rest;
	if (ctl_len == sizeof ctl_buf - 1) ctl_len = 0; /* absurd line: drop it */
}

static void read_pty(void) {
	uint8_t b[1024];
	ssize_t n = read(pty_master, b, sizeof b);
	if (n > 0) {
		stat_rx_bytes += (uint64_t)n;
		stat_rx_dropped += bq_push(&uart_rxq, b, (size_t)n);
	}
}

static void write_pty(void) {
	while (uart_txq.len) {
		uint8_t *p;
		size_t s = bq_span(&uart_txq, &p);
		ssize_t n = write(pty_master, p, s);
		if (n <= 0) break; /* EAGAIN: the host is not reading; keep it queued */
		bq_drop(&uart_txq, (size_t)n);
	}
}

/* Wait up to timeout_ns (0 = just poll, <0 = forever) for control or pty
 * input and service everything that is ready. */
static void service_io(int64_t timeout_ns) {
	struct pollfd fds[2] = {
	    {.fd = STDIN_FILENO, .events = POLLIN},
	    /* The pty is only read once the MCU runs: before that the host has not
	     * opened it yet, or is still flushing it. */
	    {.fd = pty_master, .events = (short)((running ? POLLIN : 0) | (uart_txq.len ? POLLOUT : 0))},
	};
	struct timespec ts, *tsp = NULL;
	if (timeout_ns >= 0) {
		ts.tv_sec = timeout_ns / 1000000000LL;
		ts.tv_nsec = timeout_ns % 1000000000LL;
		tsp = &ts;
	}
	int r = ppoll(fds, 2, tsp, NULL);
	if (r <= 0) return;
	if (fds[0].revents & (POLLIN | POLLHUP | POLLERR)) read_control();
	if (fds[1].revents & POLLIN) read_pty();
	if (fds[1].revents & POLLOUT) write_pty();
}

static void usage(const char *argv0) {
	fprintf(stderr,
	        "usage: %s [--speed X] [--imu-absent] [-v] firmware.elf\n"
	        "  --speed X     simulated/real time ratio (1 = real time, default; 0 = unpaced)\n"
	        "  --imu-absent  start with the MPU6050 not answering\n"
	        "  -v            log MPU register writes and simavr warnings to stderr\n",
	        argv0);
}

int main(int argc, char **argv) {
	const char *elf = NULL;
	int start_absent = 0;
	for (int i = 1; i < argc; i++) {
		if (!strcmp(argv[i], "--speed") && i + 1 < argc) speed = atof(argv[++i]);
		else if (!strcmp(argv[i], "--imu-absent")) start_absent = 1;
		else if (!strcmp(argv[i], "-v")) verbose = 1;
		else if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help")) {
			usage(argv[0]);
			return 0;
		} else if (argv[i][0] != '-' && !elf) elf = argv[i];
		else {
			usage(argv[0]);
			return 2;
		}
	}
	if (!elf) {
		usage(argv[0]);
		return 2;
	}
	signal(SIGPIPE, SIG_IGN);
	avr_global_logger_set(logger);

	elf_firmware_t fw;
	memset(&fw, 0, sizeof fw);
	if (elf_read_firmware(elf, &fw) != 0) {
		fprintf(stderr, "neck_hil: cannot read firmware %s\n", elf);
		return 2;
	}
	strcpy(fw.mmcu, "atmega328p");
	fw.frequency = 16000000;
	avr = avr_make_mcu_by_name(fw.mmcu);
	if (!avr) {
		fprintf(stderr, "neck_hil: simavr does not know atmega328p\n");
		return 2;
	}
	avr_init(avr);
	avr->log = verbose ? LOG_WARNING : LOG_ERROR;
	avr_load_firmware(avr, &fw);
	avr->frequency = 16000000;
	avr->vcc = avr->avcc = avr->aref = 5000; /* mV; analogRead uses AVCC */

	/* UART0 <-> pty. Without clearing the flags simavr would echo the UART
	 * to stdout (our control channel) and usleep() on every status poll. */
	uint32_t flags = 0;
	avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
	flags &= ~(uint32_t)(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
	avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
	uart_in_irq = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
	avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_out_hook, NULL);
	avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), uart_xon_hook, NULL);
	avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), uart_xoff_hook, NULL);
	bq_init(&uart_rxq, 1 << 16);
	bq_init(&uart_txq, 1 << 20);

	/* MPU6050 on the TWI bus. */
	mpu_defaults();
	mpu.whoami = 0x68;
	mpu.absent = start_absent;
	mpu.sensor[2] = 8192;  /* +1 g on Z at +-4 g: head level */
	mpu.sensor[3] = -3920; /* 25 C: T = raw/340 + 36.53 */
	twi_in_irq = avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_INPUT);
	avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_OUTPUT), twi_hook, NULL);

	/* Thermistor inputs at room temperature (10k/10k divider: mid-scale). */
	adc_irq_base = avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, 0);
	for (int ch = 0; ch < 3; ch++) set_adc(ch, 512);

	/* The pty, raw from the start so nothing is echoed back into the UART. */
	struct termios tio;
	memset(&tio, 0, sizeof tio);
	cfmakeraw(&tio);
	cfsetispeed(&tio, B115200);
	cfsetospeed(&tio, B115200);
	if (openpty(&pty_master, &pty_slave_keep, pty_name, &tio, NULL) < 0) {
		perror("neck_hil: openpty");
		return 2;
	}
	/* Keeping a slave fd open ourselves means the master never sees a hangup
	 * when the host closes/reopens the port. */
	fcntl(pty_master, F_SETFL, fcntl(pty_master, F_GETFL) | O_NONBLOCK);
	fcntl(STDIN_FILENO, F_SETFL, fcntl(STDIN_FILENO, F_GETFL) | O_NONBLOCK);

	out("PTY %s", pty_name);

	const avr_cycle_count_t slice = avr->frequency / 1000; /* 1 ms of MCU time */
	while (!quit) {
		if (!running || mcu_dead) {
			service_io(-1);
			continue;
		}
		avr_cycle_count_t end = avr->cycle + slice;
		while (avr->cycle < end) {
			int st = avr_run(avr);
			if (avr->pc == avr->reset_pc && avr->cycle > 0) {
				resets_seen++;
				out("RESET %llu", (unsigned long long)sim_us());
			}
			check_relays();
			uint16_t sp = (uint16_t)(avr->data[REG_SPL] | (avr->data[REG_SPH] << 8));
			if (sp && sp < sp_min) sp_min = sp;
			if (st == cpu_Done || st == cpu_Crashed) {
				out("CRASH %llu %d", (unsigned long long)sim_us(), st);
				mcu_dead = 1;
				break;
			}
		}
		uint64_t t = sim_us();
		for (int i = 0; i < N_INJECT; i++) {
			if (!inject[i].period_us || t < inject[i].next_us) continue;
			stat_rx_dropped += bq_push(&uart_rxq, inject[i].bytes, inject[i].len);
			inject[i].next_us += inject[i].period_us;
			if (inject[i].next_us < t) inject[i].next_us = t + inject[i].period_us;
		}
		uart_feed();

		int64_t wait_ns = 0;
		if (speed > 0) {
			int64_t target_ns = wall_ref_ns + (int64_t)((double)(t - sim_ref_us) * 1000.0 / speed);
			wait_ns = target_ns - wall_ns();
			if (wait_ns < -50000000LL) { /* >50 ms behind: re-anchor, never sprint to catch up */
				stat_lag_resync++;
				pace_anchor();
				wait_ns = 0;
			}
			if (wait_ns < 0) wait_ns = 0;
		}
		service_io(wait_ns);
		/* ppoll may return early on I/O: keep honouring the pace. */
		while (!quit && speed > 0 && running) {
			int64_t target_ns = wall_ref_ns + (int64_t)((double)(sim_us() - sim_ref_us) * 1000.0 / speed);
			int64_t w = target_ns - wall_ns();
			if (w <= 0) break;
			service_io(w);
		}
		uart_feed();
	}
	if (pty_master >= 0) close(pty_master);
	if (pty_slave_keep >= 0) close(pty_slave_keep);
	return 0;
}
