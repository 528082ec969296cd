/*
 * The C side of `cargo bench -p uss-benches --bench bindings`: the cost of a call through
 * libussrt, measured the way the benchmark measures the Rust and Python calls.
 *
 *   bindings BUS DRIVE BATCHES READS
 *
 * Prints "drive_read NS" (the median of BATCHES batch means of 1000 ussrt_drive_read calls)
 * and "param_read NS" (the median of READS ussrt_param_read_raw of P1082).
 */
#define _POSIX_C_SOURCE 200809L

#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include <ussrt.h>

static long long now_ns(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (long long)t.tv_sec * 1000000000LL + t.tv_nsec;
}

static int cmp(const void *a, const void *b) {
  long long x = *(const long long *)a, y = *(const long long *)b;
  return (x > y) - (x < y);
}

static long long median(long long *v, int n) {
  qsort(v, (size_t)n, sizeof *v, cmp);
  return v[n / 2];
}

int main(int argc, char **argv) {
  if (argc != 5) return 2;
  uint8_t drive = (uint8_t)atoi(argv[2]);
  int batches = atoi(argv[3]), reads = atoi(argv[4]);
  UssrtBus *bus = NULL;
  if (ussrt_bus_open(argv[1], &bus) != USSRT_STATUS_OK) {
    fprintf(stderr, "bindings: %s\n", ussrt_last_error());
    return 1;
  }
  UssrtDrive d;
  long long *means = calloc((size_t)batches, sizeof *means);
  long long *trips = calloc((size_t)reads, sizeof *trips);
  for (int b = 0; b < batches; b++) {
    long long t0 = now_ns();
    for (int i = 0; i < 1000; i++) {
      if (ussrt_drive_read(bus, drive, &d) != USSRT_STATUS_OK) return 1;
    }
    means[b] = (now_ns() - t0) / 1000;
  }
  for (int r = 0; r < reads; r++) {
    uint32_t value;
    long long t0 = now_ns();
    if (ussrt_param_read_raw(bus, drive, 1082, USSRT_NO_INDEX, &value, NULL) != USSRT_STATUS_OK) {
      fprintf(stderr, "bindings: %s\n", ussrt_last_error());
      return 1;
    }
    trips[r] = now_ns() - t0;
  }
  printf("drive_read %lld\nparam_read %lld\n", median(means, batches), median(trips, reads));
  ussrt_bus_close(bus);
  return 0;
}
