/*
 * The C front-end of the safety conformance suite (tests/tests/conformance.rs, docs/SAFETY.md):
 * a controller of libussrt driven line by line from stdin, so the suite runs the same scenario
 * against every language with real processes and signals.
 *
 * Each line is a command (open BUS ADDRESS, keepalive, run HZ, rearm [MS], ...); a line that starts
 * with '&' runs on a thread of its own (a second thread of the same program, on the same
 * handle). Every command is answered by one line: "<< ok" or "<< err KIND MESSAGE" ("<&" for a
 * thread's), KIND being ussrt_status_name of the status.
 */
#define _POSIX_C_SOURCE 200809L

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "ussrt.h"

static UssrtBus *bus;
static UssrtController *controller;
static pthread_mutex_t out_lock = PTHREAD_MUTEX_INITIALIZER;

static void answer(const char *tag, UssrtStatus s) {
  pthread_mutex_lock(&out_lock);
  if (s == USSRT_STATUS_OK) {
    printf("%s ok\n", tag);
  } else {
    printf("%s err %s %s\n", tag, ussrt_status_name((int32_t)s), ussrt_last_error());
  }
  fflush(stdout);
  pthread_mutex_unlock(&out_lock);
}

/* One command on the controller; its status. */
static UssrtStatus call(char *words) {
  char *save = NULL;
  const char *cmd = strtok_r(words, " \n", &save);
  const char *a1 = strtok_r(NULL, " \n", &save);
  const char *a2 = strtok_r(NULL, " \n", &save);
  if (cmd == NULL) return USSRT_STATUS_INVALID_ARGUMENT;
  if (!strcmp(cmd, "keepalive")) return ussrt_control_keepalive(controller);
  if (!strcmp(cmd, "enable")) return ussrt_control_enable(controller);
  if (!strcmp(cmd, "stop")) return ussrt_control_stop(controller);
  if (!strcmp(cmd, "coast")) return ussrt_control_coast(controller);
  if (!strcmp(cmd, "quick_stop")) return ussrt_control_quick_stop(controller);
  if (!strcmp(cmd, "rearm")) {
    /* Asked for when the line arrives; "rearm MS" calls MS later (a program that re-arms once
     * it is set up): a stop meanwhile is not re-armed. */
    uint64_t asked = ussrt_monotonic_ns();
    if (a1 != NULL) {
      long ms = atol(a1);
      struct timespec t = {.tv_sec = ms / 1000, .tv_nsec = (ms % 1000) * 1000000L};
      nanosleep(&t, NULL);
    }
    return ussrt_control_rearm_at(controller, asked, NULL);
  }
  if (!strcmp(cmd, "check")) {
    UssrtDrive d;
    return ussrt_control_check(controller, &d);
  }
  if (!strcmp(cmd, "run") && a1 != NULL) return ussrt_control_run_hz(controller, strtof(a1, NULL));
  if (!strcmp(cmd, "acknowledge") && a1 != NULL) {
    return ussrt_control_acknowledge_fault(controller, (uint32_t)atol(a1));
  }
  if (!strcmp(cmd, "wait_state") && a1 != NULL && a2 != NULL) {
    return ussrt_control_wait_state(controller, (uint8_t)atoi(a1), (uint32_t)atol(a2));
  }
  if (!strcmp(cmd, "set_words")) {
    /* Words in order: the first two taken above, the rest after them. */
    uint16_t w[16];
    size_t n = 0;
    if (a1 != NULL) w[n++] = (uint16_t)strtoul(a1, NULL, 0);
    if (a2 != NULL) w[n++] = (uint16_t)strtoul(a2, NULL, 0);
    for (const char *a; n < 16 && (a = strtok_r(NULL, " \n", &save)) != NULL;) {
      w[n++] = (uint16_t)strtoul(a, NULL, 0);
    }
    return ussrt_control_set_words(controller, w, n);
  }
  if (!strcmp(cmd, "release")) return ussrt_control_release(controller);
  fprintf(stderr, "conformance: unknown command %s\n", cmd);
  exit(2);
}

static void *background(void *arg) {
  char *line = arg;
  answer("<&", call(line));
  free(line);
  return NULL;
}

int main(void) {
  char line[256];
  pthread_t threads[16];
  int n = 0;
  while (fgets(line, sizeof line, stdin) != NULL) {
    if (line[0] == '&') {
      if (n == 16) return 2;
      char *copy = strdup(line + 1);
      if (copy == NULL || pthread_create(&threads[n++], NULL, background, copy) != 0) return 2;
      continue;
    }
    if (!strncmp(line, "open ", 5)) {
      char name[128];
      unsigned address;
      if (sscanf(line + 5, "%127s %u", name, &address) != 2) return 2;
      UssrtStatus s = ussrt_bus_open(name, &bus);
      if (s == USSRT_STATUS_OK) s = ussrt_control_open(bus, (uint8_t)address, &controller);
      answer("<<", s);
    } else if (!strncmp(line, "exit", 4)) {
      break;
    } else {
      answer("<<", call(line));
    }
  }
  for (int i = 0; i < n; i++) pthread_join(threads[i], NULL);
  ussrt_control_close(controller); /* hands the drive back */
  ussrt_bus_close(bus);
  return 0;
}
