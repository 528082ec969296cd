/*
 * ussrt_drive_diag from a real C program while ussd is paused (tests/tests/capi.rs): opens the
 * bus once, then for every line on stdin prints "online N" for drive 1 as the diagnostics say
 * it, so the harness can ask before and during a SIGSTOP of ussd. Diagnostics older than their
 * limit must say online 0 (rule 3: stale data says it is stale).
 */
#define _POSIX_C_SOURCE 200809L

#include <stdio.h>

#include "ussrt.h"

int main(int argc, char **argv) {
  if (argc != 2) return 2;
  UssrtBus *bus = NULL;
  if (ussrt_bus_open(argv[1], &bus) != USSRT_STATUS_OK) {
    fprintf(stderr, "diag_online: %s\n", ussrt_last_error());
    return 1;
  }
  char line[64];
  while (fgets(line, sizeof line, stdin) != NULL) {
    UssDriveDiag diag;
    UssrtStatus s = ussrt_drive_diag(bus, 1, &diag);
    if (s != USSRT_STATUS_OK) {
      printf("err %s\n", ussrt_status_name((int32_t)s));
    } else {
      printf("online %u\n", (unsigned)diag.online);
    }
    fflush(stdout);
  }
  ussrt_bus_close(bus);
  return 0;
}
