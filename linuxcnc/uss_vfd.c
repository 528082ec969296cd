/*
 * uss_vfd: a LinuxCNC userspace HAL component that runs a spindle drive through ussd, the way
 * LinuxCNC's own VFD drivers (vfs11_vfd, gs2_vfd, hy_vfd) run theirs over Modbus:
 *
 *   loadusr -Wn uss_vfd uss_vfd --bus line1 --drive 3
 *
 * It is a controller of libussrt (the C ABI of the uss-rt client), so the drive follows the
 * rules every uss-rt controller follows (docs/SAFETY.md) and adds none of its own: it runs only
 * on a live, deliberate command. A latch (ussd's start, an operator's stop, a trip, a restarted
 * ussd) holds, idle or running, until spindle-on rises (low -> high, M3) after the latch was
 * seen: that edge is the deliberate re-arm (OFF1 naming the latch), and the drive runs. A
 * spindle-on that was high when the latch came must go low and high again; at start it must be
 * seen low first. Nothing else re-arms: not spindle-on low, not an idle loop, not a reconnect.
 *
 * The watchdog is fed by this component's own loop, one command per exchange, and only while
 * LinuxCNC's servo thread proves it is alive: watchdog-in must change at least once per half
 * the drive's watchdog time (watchdog_ms of ussd's configuration), as hostmot2's watchdog and charge pumps
 * expect, e.g. from siggen's clock in the servo thread:
 *
 *   loadrt siggen
 *   addf siggen.0.update servo-thread
 *   setp siggen.0.frequency 100
 *   net uss-watchdog siggen.0.clock => uss_vfd.watchdog-in
 *
 * No change within half the watchdog time (the servo thread stopped, LinuxCNC hangs) and the
 * component sends OFF1 once and stops refreshing: ussd trips the drive (controller stale), and
 * it stays latched until spindle-on rises again (with enable high). watchdog-in is sampled every
 * millisecond: it must not change faster than every 2 ms (siggen at up to 250 Hz).
 *
 * Pins (NAME is --name, default uss_vfd):
 *   NAME.speed-command       float in   spindle speed in rpm (the sign gives the direction when
 *                                       neither spindle-fwd nor spindle-rev is set)
 *   NAME.spindle-on          bit   in   run; after a latch, its rising edge re-arms and runs
 *   NAME.spindle-fwd         bit   in   forward
 *   NAME.spindle-rev         bit   in   reverse
 *   NAME.enable              bit   in   must be high for the drive to run (low: OFF1)
 *   NAME.err-reset           bit   in   a rising edge acknowledges a drive fault
 *   NAME.watchdog-in         bit   in   toggled by the servo thread, at least once per half
 *                                       the watchdog time: the proof that LinuxCNC is alive
 *   NAME.at-speed            bit   out  running within tolerance of the command
 *   NAME.spindle-speed-fb    float out  actual speed in rpm (NaN while ussd reads the reference)
 *   NAME.spindle-speed-fb-hz float out  actual frequency in Hz (NaN likewise)
 *   NAME.frequency-command   float out  the commanded frequency in Hz (NaN likewise)
 *   NAME.fault               bit   out  the drive reports a fault (ZSW1 bit 3)
 *   NAME.fault-code          s32   out  the drive's newest fault number (r0947[0], F0072 -> 72)
 *   NAME.latched             bit   out  ussd holds the drive stopped until it is re-armed
 *   NAME.watchdog-ok         bit   out  watchdog-in changed within half the watchdog time
 *   NAME.comm-ok             bit   out  ussd serves the bus and the drive answers
 *   NAME.error-count         s32   out  failed calls and lost contacts since the start
 *   NAME.state               s32   out  PROFIdrive state: 1..4 for S1..S4, 6 fault, 0 not ready
 * Parameters:
 *   NAME.rpm-per-hz          float rw   spindle rpm per Hz of the motor's frequency (the motor's
 *                                       poles and the gearing: 30 for a 4-pole motor direct, 1500
 *                                       rpm at 50 Hz); the command goes out in Hz, scaled by the
 *                                       drive's reference P2000 as ussd reads it: a changed P2000
 *                                       changes no speed, and no setpoint goes out while ussd
 *                                       reads it again
 *   NAME.tolerance           float rw   at-speed tolerance, a fraction of the command (0.02)
 */
#define _POSIX_C_SOURCE 200809L

#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "hal.h"
#include "ussrt.h"

typedef struct {
  hal_float_t *speed_command;
  hal_bit_t *spindle_on;
  hal_bit_t *spindle_fwd;
  hal_bit_t *spindle_rev;
  hal_bit_t *enable;
  hal_bit_t *err_reset;
  hal_bit_t *watchdog_in;
  hal_bit_t *at_speed;
  hal_float_t *speed_fb;
  hal_float_t *speed_fb_hz;
  hal_float_t *frequency_command;
  hal_bit_t *fault;
  hal_s32_t *fault_code;
  hal_bit_t *latched;
  hal_bit_t *watchdog_ok;
  hal_bit_t *comm_ok;
  hal_s32_t *error_count;
  hal_s32_t *state;
  hal_float_t rpm_per_hz;
  hal_float_t tolerance;
} pins_t;

static volatile sig_atomic_t done;

static void quit(int signal) {
  (void)signal;
  done = 1;
}

static void usage(void) {
  fprintf(stderr, "usage: uss_vfd --bus BUS --drive ADDRESS [--name NAME]\n");
}

/* What the component knows between two loops. */
typedef struct {
  const char *name;
  const char *bus_name;
  uint8_t address;
  UssrtBus *bus;
  UssrtController *c;
  /* A latch was seen (or none can be ruled out: the start, a new controller): the drive runs
   * only after spindle-on rises, which re-arms it. */
  int latched;
  int was_on;
  /* When spindle-on was last read low (CLOCK_MONOTONIC ns): its rise came after, so a re-arm
   * by the rise is asked for no earlier than this, and a stop that began since is not
   * re-armed by it (the loop reads the pin only every refresh period). */
  uint64_t low_seen_ns;
  int was_fault;
  int was_reset;
  int was_comm;
  int complained;
  /* The controller's refresh period (ussrt_control_refresh_period), us; 20 ms without one. */
  uint32_t refresh_us;
  /* The drive's watchdog time, ms (100 until ussd says). */
  uint32_t watchdog_ms;
  /* watchdog-in as last sampled, and when it last changed (CLOCK_MONOTONIC, ms). */
  int watchdog_was;
  double watchdog_at;
} vfd_t;

static double now_ms(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec * 1e3 + (double)t.tv_nsec / 1e6;
}

/* Samples watchdog-in. */
static void sample_watchdog(vfd_t *v, pins_t *p) {
  int in = *p->watchdog_in != 0;
  if (in != v->watchdog_was) {
    v->watchdog_was = in;
    v->watchdog_at = now_ms();
  }
}

static void say(vfd_t *v, const char *what, UssrtStatus s) {
  /* One line per kind of failure in a row, not one per loop. */
  if (v->complained != (int)s) {
    fprintf(stderr, "%s: %s: %s\n", v->name, what, ussrt_last_error());
    v->complained = (int)s;
  }
}

/* Lets go of bus and controller (the controller hands the drive back). */
static void disconnect(vfd_t *v) {
  ussrt_control_close(v->c);
  v->c = NULL;
  v->refresh_us = 20000;
  ussrt_bus_close(v->bus);
  v->bus = NULL;
}

/* Opens bus and controller when they are not; 0 when both are there. */
static int connect(vfd_t *v, pins_t *p) {
  UssrtStatus s;
  if (v->bus == NULL) {
    s = ussrt_bus_open(v->bus_name, &v->bus);
    if (s != USSRT_STATUS_OK) {
      say(v, "bus", s);
      return -1;
    }
  }
  if (v->c == NULL) {
    s = ussrt_control_open(v->bus, v->address, &v->c);
    if (s != USSRT_STATUS_OK) {
      say(v, "control", s);
      (*p->error_count)++;
      return -1;
    }
    (void)ussrt_control_refresh_period(v->c, &v->refresh_us);
    /* A new controller re-arms nothing: the drive runs only after spindle-on rises. */
    v->latched = 1;
  }
  return 0;
}

static void outputs_off(pins_t *p) {
  *p->at_speed = 0;
  *p->comm_ok = 0;
}

/* One loop: read the drive, decide the command, send it (the watchdog refresh). */
static void step(vfd_t *v, pins_t *p) {
  if (connect(v, p) != 0) {
    outputs_off(p);
    return;
  }
  UssrtDrive d;
  UssrtStatus s = ussrt_drive_read(v->bus, v->address, &d);
  if (s != USSRT_STATUS_OK) {
    say(v, "read", s);
    (*p->error_count)++;
    outputs_off(p);
    return;
  }
  if (d.watchdog_ms > 0) v->watchdog_ms = d.watchdog_ms;
  int comm = !d.stale && d.image.online;
  if (v->was_comm && !comm) (*p->error_count)++;
  v->was_comm = comm;
  *p->comm_ok = comm;
  *p->state = d.state;
  *p->fault = d.state == 6;
  /* rpm are Hz at the motor times rpm-per-hz, a constant of the machine; Hz are scaled by the
   * drive's reference P2000 as ussd reads it (libussrt), never by a number of this file: a
   * P2000 changed at the drive (found by issue 46's sweep: 60 Hz for 50 ran the spindle 20 %
   * fast and showed it at the command) changes no speed. While ussd reads the reference again
   * (a reset, a restart, the drive back online) the feedback is NaN and no setpoint goes out. */
  double rpm_per_hz = p->rpm_per_hz > 0 ? p->rpm_per_hz : 1.0;
  *p->speed_fb_hz = d.actual_hz;
  *p->speed_fb = d.actual_hz * rpm_per_hz;

  /* The drive's newest fault number, read once per fault. */
  if (*p->fault && !v->was_fault) {
    UssrtValue f;
    if (ussrt_param_read(v->bus, v->address, "r0947[0]", &f) == USSRT_STATUS_OK) {
      *p->fault_code = (hal_s32_t)f.value;
    }
  }
  v->was_fault = *p->fault;

  double command = *p->speed_command;
  int reverse = (*p->spindle_rev && !*p->spindle_fwd) ||
                (!*p->spindle_fwd && !*p->spindle_rev && command < 0);
  double hz = fabs(command) / rpm_per_hz * (reverse ? -1 : 1);
  *p->frequency_command = hz;
  const uint64_t read_at = ussrt_monotonic_ns();
  int on = *p->spindle_on;
  if (!on) v->low_seen_ns = read_at;
  int rose = on && !v->was_on;
  v->was_on = on;
  int run = on && *p->enable;

  /* LinuxCNC's servo thread is alive, or this component stops the drive once (OFF1: a stop
   * always goes out) and then sends nothing at all: ussd's watchdog trips it as it trips a dead
   * controller. Half the drive's watchdog time without a change is enough to say so. */
  *p->watchdog_ok = now_ms() - v->watchdog_at <= (double)v->watchdog_ms / 2;
  if (!*p->watchdog_ok) {
    if (!v->latched) (void)ussrt_control_stop(v->c);
    v->latched = 1;
    if (v->complained != -1) {
      fprintf(stderr, "%s: watchdog-in has not changed within %u ms (half the drive's "
              "watchdog): the drive stopped, not refreshing it; is the servo thread running?\n",
              v->name, (unsigned)(v->watchdog_ms / 2));
      v->complained = -1;
    }
    *p->latched = 1;
    *p->at_speed = 0;
    return;
  }
  /* A latch seen in the image is one the next rising edge re-arms. */
  if (!d.live) v->latched = 1;

  if (v->latched && rose && *p->enable) {
    /* The deliberate re-arm: spindle-on rose after the latch was seen, with enable high (a
     * rise while enable is low re-arms nothing: enable going high later starts no spindle).
     * It carries the rise's time: a stop that came after the pin was last seen low (an
     * operator's coast right after M3) is not re-armed, and waits for the next rise. */
    s = ussrt_control_rearm_at(v->c, v->low_seen_ns, NULL);
    if (s == USSRT_STATUS_OK) v->latched = 0;
  } else {
    s = USSRT_STATUS_OK;
  }
  if (s == USSRT_STATUS_OK) {
    /* Latched, off or disabled: OFF1 (a stop always goes out; it re-arms nothing). */
    s = (!v->latched && run) ? ussrt_control_run_hz(v->c, (float)hz) : ussrt_control_stop(v->c);
    /* The reference is being read again: nothing is scaled with the old one, so stop (OFF1, no
     * latch) until it is known; the live spindle-on runs the drive again then. */
    if (s == USSRT_STATUS_REFERENCE_UNKNOWN) s = ussrt_control_stop(v->c);
  }
  if (*p->err_reset && !v->was_reset && s == USSRT_STATUS_OK) {
    s = ussrt_control_acknowledge_fault(v->c, 1000);
  }
  v->was_reset = *p->err_reset;

  switch (s) {
  case USSRT_STATUS_OK:
    v->complained = 0;
    break;
  case USSRT_STATUS_TRIPPED:
  case USSRT_STATUS_NOT_ARMED:
  case USSRT_STATUS_STALLED:
    /* Latched: nothing runs the drive until spindle-on rises again. */
    v->latched = 1;
    say(v, "latched", s);
    break;
  case USSRT_STATUS_RELEASED:
  case USSRT_STATUS_CONTROLLED:
    disconnect(v);
    (*p->error_count)++;
    break;
  default:
    say(v, "command", s);
    (*p->error_count)++;
    break;
  }
  UssrtDrive now;
  if (ussrt_drive_read(v->bus, v->address, &now) == USSRT_STATUS_OK) d = now;
  /* A stale image (ussd gone or stopped, the line down) is no live drive either. */
  *p->latched = !d.live || v->latched || !comm;
  double want = fabs(command);
  double got = fabs(*p->speed_fb);
  *p->at_speed = comm && !*p->latched && run && d.state == 4 && want > 0 &&
                 fabs(got - want) <= p->tolerance * want + 1e-6;
}

int main(int argc, char **argv) {
  /* was_on = 1: spindle-on must be seen low before its first rise runs the drive. */
  vfd_t v = {.name = "uss_vfd",
             .bus_name = NULL,
             .address = 0xFF,
             .refresh_us = 20000,
             .watchdog_ms = 100,
             .latched = 1,
             .was_on = 1};
  for (int i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "--bus") && i + 1 < argc) {
      v.bus_name = argv[++i];
    } else if (!strcmp(argv[i], "--drive") && i + 1 < argc) {
      char *end = NULL;
      long a = strtol(argv[++i], &end, 10);
      if (*end != '\0' || a < 0 || a > 31) {
        fprintf(stderr, "uss_vfd: --drive %s: a drive address is 0..31\n", argv[i]);
        return 1;
      }
      v.address = (uint8_t)a;
    } else if ((!strcmp(argv[i], "--name") || !strcmp(argv[i], "-n")) && i + 1 < argc) {
      v.name = argv[++i];
    } else {
      usage();
      return 1;
    }
  }
  if (v.bus_name == NULL || v.address == 0xFF) {
    usage();
    return 1;
  }

  int comp = hal_init(v.name);
  if (comp < 0) {
    fprintf(stderr, "%s: hal_init failed (%d)\n", v.name, comp);
    return 1;
  }
  signal(SIGINT, quit);
  signal(SIGTERM, quit);
  pins_t *p = hal_malloc(sizeof *p);
  int r = p == NULL;
  if (!r) {
    const char *n = v.name;
    r |= hal_pin_float_newf(HAL_IN, &p->speed_command, comp, "%s.speed-command", n);
    r |= hal_pin_bit_newf(HAL_IN, &p->spindle_on, comp, "%s.spindle-on", n);
    r |= hal_pin_bit_newf(HAL_IN, &p->spindle_fwd, comp, "%s.spindle-fwd", n);
    r |= hal_pin_bit_newf(HAL_IN, &p->spindle_rev, comp, "%s.spindle-rev", n);
    r |= hal_pin_bit_newf(HAL_IN, &p->enable, comp, "%s.enable", n);
    r |= hal_pin_bit_newf(HAL_IN, &p->err_reset, comp, "%s.err-reset", n);
    r |= hal_pin_bit_newf(HAL_IN, &p->watchdog_in, comp, "%s.watchdog-in", n);
    r |= hal_pin_bit_newf(HAL_OUT, &p->at_speed, comp, "%s.at-speed", n);
    r |= hal_pin_float_newf(HAL_OUT, &p->speed_fb, comp, "%s.spindle-speed-fb", n);
    r |= hal_pin_float_newf(HAL_OUT, &p->speed_fb_hz, comp, "%s.spindle-speed-fb-hz", n);
    r |= hal_pin_float_newf(HAL_OUT, &p->frequency_command, comp, "%s.frequency-command", n);
    r |= hal_pin_bit_newf(HAL_OUT, &p->fault, comp, "%s.fault", n);
    r |= hal_pin_s32_newf(HAL_OUT, &p->fault_code, comp, "%s.fault-code", n);
    r |= hal_pin_bit_newf(HAL_OUT, &p->latched, comp, "%s.latched", n);
    r |= hal_pin_bit_newf(HAL_OUT, &p->watchdog_ok, comp, "%s.watchdog-ok", n);
    r |= hal_pin_bit_newf(HAL_OUT, &p->comm_ok, comp, "%s.comm-ok", n);
    r |= hal_pin_s32_newf(HAL_OUT, &p->error_count, comp, "%s.error-count", n);
    r |= hal_pin_s32_newf(HAL_OUT, &p->state, comp, "%s.state", n);
    r |= hal_param_float_newf(HAL_RW, &p->rpm_per_hz, comp, "%s.rpm-per-hz", n);
    r |= hal_param_float_newf(HAL_RW, &p->tolerance, comp, "%s.tolerance", n);
  }
  if (r) {
    fprintf(stderr, "%s: creating the pins failed\n", v.name);
    hal_exit(comp);
    return 1;
  }
  *p->speed_command = 0;
  *p->spindle_on = *p->spindle_fwd = *p->spindle_rev = *p->err_reset = *p->watchdog_in = 0;
  *p->enable = 1;
  *p->at_speed = *p->fault = *p->comm_ok = *p->watchdog_ok = 0;
  *p->latched = 1;
  *p->speed_fb = *p->speed_fb_hz = *p->frequency_command = 0;
  *p->fault_code = *p->error_count = *p->state = 0;
  p->rpm_per_hz = 30.0; /* a 4-pole motor direct: 1500 rpm at 50 Hz */
  p->tolerance = 0.02;
  v.watchdog_at = now_ms() - 1e9; /* no change seen yet */
  hal_ready(comp);

  while (!done) {
    step(&v, p);
    /* In step with the bus: the next exchange with the drive, at most the controller's refresh
     * period (a quarter of the drive's watchdog time, at most 20 ms), so this loop's own
     * command feeds the watchdog whatever its length and however slow the line; waited for in
     * 1 ms slices, watchdog-in sampled in each. Any failure but a timeout (no ussd) waits
     * 20 ms before the next try. */
    uint32_t wait_ms = v.refresh_us < 2000 ? 1 : v.refresh_us / 1000;
    UssrtStatus s = USSRT_STATUS_TIMEOUT;
    for (uint32_t waited = 0; waited < wait_ms && s == USSRT_STATUS_TIMEOUT && !done; waited++) {
      s = v.bus == NULL ? USSRT_STATUS_NOT_RUNNING : ussrt_wait_exchange(v.bus, v.address, 1);
      sample_watchdog(&v, p);
    }
    if (s != USSRT_STATUS_OK && s != USSRT_STATUS_TIMEOUT) {
      for (int i = 0; i < 20 && !done; i++) {
        struct timespec pause = {0, 1000 * 1000};
        nanosleep(&pause, NULL);
        sample_watchdog(&v, p);
      }
    }
  }
  disconnect(&v); /* hands the drive back: ussd sends its safe command, "released" */
  hal_exit(comp);
  return 0;
}
