/*
 * run_drive: a C control loop on libussrt. Reads a drive and its P1082, takes control,
 * re-arms it, runs it towards HZ for SECONDS in step with the bus (one keepalive per exchange,
 * the program's own call), stops it along its ramp and hands it back.
 *
 *   cc -std=c11 run_drive.c $(pkg-config --cflags --libs ussrt) -o run_drive
 *   ./run_drive bus0 1 10 2
 *
 * Any failure prints the library's message and exits 1; a latch (an operator's stop, a trip)
 * says why. The drive is handed back on every path (ussrt_control_close).
 */
#define _POSIX_C_SOURCE 200809L /* clock_gettime, nanosleep */

#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include <ussrt.h>

static const char *state_name(uint8_t s) {
  static const char *names[] = {"not ready", "S1", "S2", "S3", "S4", "S5", "fault"};
  return s < 7 ? names[s] : "?";
}

static int failed(const char *what, UssrtStatus status) {
  UssrtErrorInfo info;
  ussrt_last_error_info(&info);
  fprintf(stderr, "run_drive: %s: %s (status %d", what, ussrt_last_error(), (int)status);
  if (status == USSRT_STATUS_TRIPPED || status == USSRT_STATUS_NOT_ARMED) {
    fprintf(stderr, ", latch reason %u, command %u", info.latch_reason, info.latch_command);
  }
  fprintf(stderr, ")\n");
  return 1;
}

static double seconds_since(const struct timespec *t0) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)(t.tv_sec - t0->tv_sec) + (double)(t.tv_nsec - t0->tv_nsec) / 1e9;
}

int main(int argc, char **argv) {
  if (argc != 5) {
    fprintf(stderr, "usage: run_drive BUS DRIVE HZ SECONDS\n");
    return 2;
  }
  const char *name = argv[1];
  uint8_t address = (uint8_t)atoi(argv[2]);
  float hz = (float)atof(argv[3]);
  double seconds = atof(argv[4]);

  UssrtBus *bus = NULL;
  UssrtStatus s = ussrt_bus_open(name, &bus);
  if (s != USSRT_STATUS_OK) return failed("open", s);

  UssrtDrive d;
  s = ussrt_drive_read(bus, address, &d);
  if (s != USSRT_STATUS_OK) return failed("read", s);
  printf("%s drive %u: %s, %s, %.2f Hz of %.2f Hz\n", name, address, state_name(d.state),
         d.live ? "live" : "latched", d.actual_hz, d.reference_hz);

  UssrtValue p1082;
  s = ussrt_param_read(bus, address, "P1082", &p1082);
  if (s != USSRT_STATUS_OK) return failed("P1082", s);
  printf("%s\n", p1082.text);

  UssrtController *c = NULL;
  s = ussrt_control_open(bus, address, &c);
  if (s != USSRT_STATUS_OK) return failed("control", s);
  int rc = 0;
  /* The re-arm was asked for when this program started: a stop while it starts stays. */
  uint64_t started_ns = 0;
  s = ussrt_process_start_ns(&started_ns);
  if (s == USSRT_STATUS_OK) s = ussrt_control_rearm_at(c, started_ns, &d);
  if (s != USSRT_STATUS_OK) {
    rc = failed("rearm", s);
    goto done;
  }
  printf("drive %u: re-armed; running towards %.1f Hz\n", address, hz);
  struct timespec t0;
  clock_gettime(CLOCK_MONOTONIC, &t0);
  int reached = 0;
  while (seconds_since(&t0) < seconds) {
    /* One command per exchange: the program's own call keeps the watchdog fed. */
    s = ussrt_control_run_hz(c, hz);
    if (s != USSRT_STATUS_OK) {
      rc = failed("run", s);
      goto done;
    }
    s = ussrt_wait_exchange(bus, address, 500);
    if (s != USSRT_STATUS_OK) {
      rc = failed("wait", s);
      goto done;
    }
    s = ussrt_control_check(c, &d);
    if (s != USSRT_STATUS_OK) {
      rc = failed("check", s);
      goto done;
    }
    /* Reached: the drive's actual value is the setpoint that went out. */
    if (!reached && d.state == 4 && d.image.hiw == d.image.sent_setpoint) {
      reached = 1;
      printf("drive %u: %s at %.2f Hz\n", address, state_name(d.state), d.actual_hz);
    }
  }
  s = ussrt_control_stop(c);
  if (s == USSRT_STATUS_OK) s = ussrt_control_wait_state(c, 2, 30000);
  if (s != USSRT_STATUS_OK) {
    rc = failed("stop", s);
    goto done;
  }
  s = ussrt_control_release(c);
  if (s != USSRT_STATUS_OK) {
    rc = failed("release", s);
    goto done;
  }
  printf("drive %u: stopped (OFF1, S2) and released\n", address);
done:
  ussrt_control_close(c);
  ussrt_bus_close(bus);
  return rc;
}
