/*
 * abi_check: every kind of call of the C ABI against a real ussd (started by capi's Rust
 * test, tests/tests/capi.rs): statuses, messages, the latch as an error code with its
 * reason, the drive's error number, a stall, a release. Exits 1 at the first wrong answer.
 *
 *   abi_check BUS    (drives 1 and 2, 100 ms watchdog)
 */
#define _POSIX_C_SOURCE 200809L /* clock_gettime, nanosleep */

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <ussrt.h>

static int checks;

#define EXPECT(cond, ...)                                                                  \
  do {                                                                                     \
    checks++;                                                                              \
    if (!(cond)) {                                                                         \
      fprintf(stderr, "abi_check:%d: %s: ", __LINE__, #cond);                              \
      fprintf(stderr, __VA_ARGS__);                                                        \
      fprintf(stderr, " (last error: %s)\n", ussrt_last_error());                          \
      exit(1);                                                                             \
    }                                                                                      \
  } while (0)

#define OK(call) EXPECT((call) == USSRT_STATUS_OK, "%s", #call)

static void sleep_ms(long ms) {
  struct timespec t = {ms / 1000, (ms % 1000) * 1000000L};
  nanosleep(&t, NULL);
}

static UssrtErrorInfo info(void) {
  UssrtErrorInfo i;
  ussrt_last_error_info(&i);
  return i;
}

int main(int argc, char **argv) {
  if (argc != 2) return 2;
  const char *name = argv[1];
  UssrtBus *bus = NULL;
  UssrtDrive d;
  UssrtValue v;

  EXPECT(ussrt_bus_open("no-ussd-here", &bus) == USSRT_STATUS_NOT_RUNNING, "no ussd");
  EXPECT(strstr(ussrt_last_error(), "ussd is not running on no-ussd-here") != NULL, "message");
  EXPECT(info().status == USSRT_STATUS_NOT_RUNNING, "info");
  EXPECT(ussrt_bus_open("a/b", &bus) == USSRT_STATUS_INVALID_ARGUMENT, "bad name");
  EXPECT(ussrt_bus_open(NULL, &bus) == USSRT_STATUS_INVALID_ARGUMENT, "NULL name");
  OK(ussrt_bus_open(name, &bus));
  EXPECT(*ussrt_last_error() == '\0', "a success clears the message");

  uint32_t drives = 0;
  OK(ussrt_bus_drives(bus, &drives));
  EXPECT(drives == 0x6, "drives 1 and 2: %#x", drives);
  EXPECT(ussrt_drive_read(bus, 9, &d) == USSRT_STATUS_UNKNOWN_DRIVE, "drive 9");
  EXPECT(ussrt_drive_read(bus, 1, NULL) == USSRT_STATUS_INVALID_ARGUMENT, "NULL drive");
  OK(ussrt_wait_exchange(bus, 1, 2000));
  OK(ussrt_drive_read(bus, 1, &d));
  EXPECT(d.image.version == USS_LAYOUT_VERSION && d.image.online == 1 && d.stale == 0, "online");
  EXPECT(d.live == 0 && d.image.latch_reason == USS_LATCH_REASON_STARTUP, "latched at start");
  EXPECT(d.image.latch_id != 0 && d.state == 2 && d.image.sent_stw1 == 0x047E, "S2, OFF1");
  EXPECT(d.reference_hz == 50.0f && d.watchdog_ms == 100, "info %f %u", d.reference_hz,
         d.watchdog_ms);
  /* The bus and drive as ussd publishes them (uss_shm_types.h). */
  OK(ussrt_bus_health(bus));
  UssBusStatus status;
  OK(ussrt_bus_status(bus, &status));
  EXPECT(status.version == USS_LAYOUT_VERSION && status.drive_count == 2 && status.running == 1 &&
             status.good > 0,
         "bus status: %u drives, %llu good", status.drive_count, (unsigned long long)status.good);
  EXPECT(ussrt_bus_status(bus, NULL) == USSRT_STATUS_INVALID_ARGUMENT, "NULL status");
  UssDriveDiag diag;
  OK(ussrt_drive_diag(bus, 1, &diag));
  EXPECT(diag.info.pzd_words == 2 && diag.info.watchdog_ms == 100, "diag info %u %u",
         diag.info.pzd_words, diag.info.watchdog_ms);
  EXPECT(ussrt_drive_diag(bus, 9, &diag) == USSRT_STATUS_UNKNOWN_DRIVE, "diag of drive 9");

  /* Parameters. */
  OK(ussrt_param_read(bus, 1, "P1082", &v));
  EXPECT(strcmp(v.text, "P1082 = 50.00 Hz") == 0 && strcmp(v.unit, "Hz") == 0, "%s", v.text);
  EXPECT(v.value == 50.0 && v.raw == 0x42480000 && v.is_dword && v.is_float, "P1082 value");
  uint32_t raw = 0;
  uint8_t dword = 0;
  OK(ussrt_param_read_raw(bus, 1, 2000, USSRT_NO_INDEX, &raw, &dword));
  EXPECT(raw == 0x42480000 && dword == 1, "P2000 raw %#x", raw);
  EXPECT(ussrt_param_read(bus, 1, "P1999", &v) == USSRT_STATUS_DRIVE_ERROR, "P1999");
  EXPECT(info().drive_error == 0, "error 0: illegal PNU, got %u", info().drive_error);
  EXPECT(ussrt_param_read(bus, 1, "Q12", &v) == USSRT_STATUS_INVALID_ARGUMENT, "notation");
  /* A drive ussd does not poll: the same status as its diagnostics, not "refused". */
  EXPECT(ussrt_param_read(bus, 9, "P0003", &v) == USSRT_STATUS_UNKNOWN_DRIVE, "P0003 of drive 9");
  EXPECT(ussrt_param_read_raw(bus, 9, 3, USSRT_NO_INDEX, &raw, &dword) ==
             USSRT_STATUS_UNKNOWN_DRIVE,
         "raw P0003 of drive 9");
  EXPECT(ussrt_param_write(bus, 2, "P0700", "70000", 0, &v) == USSRT_STATUS_VALUE, "70000");
  EXPECT(strstr(ussrt_last_error(), "70000 does not fit") != NULL, "says why");
  OK(ussrt_param_write(bus, 1, "P1120", "0.5", 0, &v));
  EXPECT(strcmp(v.text, "P1120 = 0.50 s") == 0, "%s", v.text);
  OK(ussrt_param_write(bus, 1, "P1121", "0.5", 0, NULL));
  EXPECT(ussrt_param_write(bus, 1, "P1120", "1", 8, NULL) == USSRT_STATUS_INVALID_ARGUMENT,
         "flags");
  /* A batch of chosen items: one request, a result each; an item's failure is its own. */
  const UssrtParamItem items[4] = {
      {.pnu = 1082, .index = USSRT_NO_INDEX},
      {.pnu = 1121, .write = 1, .dword = 1, .index = USSRT_NO_INDEX, .value = 0x3F000000},
      {.pnu = 1999, .index = USSRT_NO_INDEX},
      {.pnu = 947, .index = 0},
  };
  UssrtParamResult results[4];
  OK(ussrt_param_batch(bus, 1, items, 4, 0, results));
  EXPECT(results[0].status == USSRT_STATUS_OK && results[0].value == 0x42480000 &&
             results[0].is_dword,
         "P1082 %#x", results[0].value);
  EXPECT(results[1].status == USSRT_STATUS_OK && results[1].value == 0x3F000000, "P1121 := 0.5");
  EXPECT(results[2].status == USSRT_STATUS_DRIVE_ERROR && results[2].drive_error == 0,
         "P1999: %d %u", results[2].status, results[2].drive_error);
  EXPECT(results[3].status == USSRT_STATUS_OK && !results[3].is_dword, "r0947[0]");
  EXPECT(ussrt_param_batch(bus, 1, items, 0, 0, results) == USSRT_STATUS_INVALID_ARGUMENT,
         "an empty batch");
  EXPECT(ussrt_param_batch(bus, 1, items, 40, 0, results) == USSRT_STATUS_INVALID_ARGUMENT,
         "40 items");
  EXPECT(ussrt_param_batch(bus, 1, items, 4, USSRT_WRITE_UNSAFE, results) ==
             USSRT_STATUS_INVALID_ARGUMENT,
         "unsafe");
  /* Every element of an array parameter named without one. */
  UssrtValue elements[8];
  size_t element_count = 0;
  OK(ussrt_param_read_elements(bus, 1, "r0947", elements, 8, &element_count));
  EXPECT(element_count == 8 && strncmp(elements[7].text, "r0947[7] = ", 11) == 0, "%zu: %s",
         element_count, elements[7].text);
  EXPECT(ussrt_param_read_elements(bus, 1, "r0947", elements, 4, &element_count) ==
                 USSRT_STATUS_INVALID_ARGUMENT &&
             element_count == 8,
         "room for 4 of 8: %zu", element_count);
  OK(ussrt_param_read_elements(bus, 1, "P1082", elements, 1, &element_count));
  EXPECT(element_count == 1 && elements[0].value == 50.0, "one plain parameter");
  UssrtFaultReport faults;
  OK(ussrt_fault_report(bus, 1, &faults));
  EXPECT(faults.fault_count <= 8, "faults %u", faults.fault_count);
  EXPECT(faults.codes_pnu == 947, "a MICROMASTER 4 keeps its faults in r0947: %u", faults.codes_pnu);
  /* Copy RAM to ROM (P0971, level 3): the access level is raised for it and put back. */
  OK(ussrt_param_save(bus, 1));
  UssrtValue level;
  OK(ussrt_param_read(bus, 1, "P0003", &level));
  EXPECT(level.value == 1, "P0003 put back: %g", level.value);

  /* A backup (the upload's TOML) and a comparison of the drive with it. */
  size_t length = 0;
  EXPECT(ussrt_param_backup(bus, 1, NULL, 0, &length) == USSRT_STATUS_INVALID_ARGUMENT &&
             length > 100,
         "the room a backup needs: %zu", length);
  char *backup = malloc(length + 1);
  OK(ussrt_param_backup(bus, 1, backup, length + 1, &length));
  EXPECT(strncmp(backup, "# uss-rt parameter backup", 25) == 0 && strlen(backup) == length,
         "%.40s", backup);
  /* Asked to, a backup holds what the drive describes beyond the catalogue (drive 2 has a
     P0701 that uss-rt's catalogue does not list); a range that is none is refused, by the
     library, as a value that does not fit. */
  size_t found_length = 0;
  EXPECT(ussrt_param_backup_discover(bus, 2, 710, 700, NULL, 0, &found_length) ==
             USSRT_STATUS_VALUE,
         "discover 710..=700");
  char *found = malloc(16384);
  OK(ussrt_param_backup_discover(bus, 2, 700, 710, found, 16384, &found_length));
  EXPECT(strstr(found, "[described.P0701]") != NULL && strstr(found, "[described.P0700]") == NULL,
         "%s", found);
  free(found);
  size_t differ = 99, same = 0;
  OK(ussrt_param_diff(bus, 1, backup, &differ, &same));
  EXPECT(differ == 0 && same > 40, "differ %zu same %zu", differ, same);
  OK(ussrt_param_diff(bus, 2, backup, &differ, NULL));
  EXPECT(differ >= 1, "drive 2 differs at least in its address: %zu", differ);
  /* Drive 1's backup restored to drive 2: a dry run writes nothing; then what differs goes
     in (its own address kept), and drive 2 equals drive 1 but for that. */
  UssrtRestore restored;
  OK(ussrt_param_restore(bus, 2, backup, USSRT_RESTORE_DRY_RUN, &restored));
  EXPECT(restored.written == 0 && restored.kept == 1, "dry run: %u written", restored.written);
  /* A restore cut short by its cancel (asked here before it starts, as a signal handler or
     another thread would): nothing written, not complete, nothing left raised. */
  UssrtCancel *cancel = NULL;
  OK(ussrt_cancel_new(&cancel));
  OK(ussrt_cancel(cancel));
  EXPECT(ussrt_cancel(NULL) == USSRT_STATUS_INVALID_ARGUMENT, "cancel NULL");
  OK(ussrt_param_restore_cancellable(bus, 2, backup, USSRT_RESTORE_UNSAFE, cancel, &restored));
  EXPECT(restored.complete == 0 && restored.written == 0 && restored.left_raised == 0,
         "cancelled: complete %u written %u left raised %u", restored.complete, restored.written,
         restored.left_raised);
  ussrt_cancel_free(cancel);
  ussrt_cancel_free(NULL);
  OK(ussrt_param_diff(bus, 2, backup, &differ, NULL));
  EXPECT(differ > 1, "the cancelled restore wrote nothing: %zu differ", differ);
  OK(ussrt_param_restore(bus, 2, backup, USSRT_RESTORE_UNSAFE, &restored));
  EXPECT(restored.complete == 1 && restored.kept == 1 && restored.refused == 0,
         "complete %u kept %u refused %u", restored.complete, restored.kept, restored.refused);
  OK(ussrt_param_diff(bus, 2, backup, &differ, NULL));
  EXPECT(differ == 1, "only the address differs now: %zu", differ);
  EXPECT(ussrt_param_restore(bus, 2, backup, 64, &restored) == USSRT_STATUS_INVALID_ARGUMENT,
         "flag 64");
  free(backup);
  EXPECT(ussrt_param_diff(bus, 1, "format = 7", &differ, NULL) == USSRT_STATUS_VALUE,
         "a file that fails its checks");

  /* Control: the same rules as Rust and Python. */
  UssrtController *c = NULL, *second = NULL;
  OK(ussrt_control_open(bus, 1, &c));
  EXPECT(ussrt_control_open(bus, 1, &second) == USSRT_STATUS_CONTROLLED, "one controller");
  /* Opening re-arms nothing: a keepalive and a stop go out, an ON is the start-up latch. */
  OK(ussrt_control_keepalive(c));
  OK(ussrt_control_enable(c));
  EXPECT(ussrt_control_run_hz(c, 10.0f) == USSRT_STATUS_TRIPPED, "ON before the re-arm");
  EXPECT(info().latch_reason == USS_LATCH_REASON_STARTUP, "why: %u", info().latch_reason);
  uint64_t started = 0;
  OK(ussrt_process_start_ns(&started));
  EXPECT(started > 0 && started <= ussrt_monotonic_ns(), "started %llu", (unsigned long long)started);
  EXPECT(ussrt_process_start_ns(NULL) == USSRT_STATUS_INVALID_ARGUMENT, "NULL start");
  OK(ussrt_control_rearm_at(c, started, &d));
  EXPECT(d.live == 1, "re-armed");
  OK(ussrt_control_run_hz(c, 10.0f));
  OK(ussrt_control_wait_state(c, 4, 5000));
  /* A new setpoint keeps the control word; a jog is STW1 bit 8 or 9 on OFF1's word. */
  OK(ussrt_control_set_hz(c, 5.0f));
  OK(ussrt_wait_exchange(bus, 1, 2000));
  OK(ussrt_wait_exchange(bus, 1, 2000));
  OK(ussrt_drive_read(bus, 1, &d));
  EXPECT(d.image.sent_stw1 == 0x047F, "still ON: %#x", d.image.sent_stw1);
  EXPECT(ussrt_control_set_hz(c, 1.0f / 0.0f) == USSRT_STATUS_INVALID_ARGUMENT, "inf Hz");
  /* Beyond the setpoint word's -200 % .. +199.99 %: refused, not sent as full scale. */
  EXPECT(ussrt_control_set_hz(c, 5000.0f) == USSRT_STATUS_INVALID_ARGUMENT, "5000 Hz");
  EXPECT(ussrt_control_run_percent(c, -250.0f) == USSRT_STATUS_INVALID_ARGUMENT, "-250 percent");
  /* A MICROMASTER's reference is a frequency: an rpm setpoint has nothing to scale by. */
  EXPECT(ussrt_control_run_rpm(c, 1500.0f) == USSRT_STATUS_INVALID_ARGUMENT, "1500 rpm on MM4");
  EXPECT(ussrt_control_jog(c, 3) == USSRT_STATUS_INVALID_ARGUMENT, "jog 3");
  OK(ussrt_control_stop(c));
  OK(ussrt_control_wait_state(c, 2, 5000));
  OK(ussrt_control_jog(c, USSRT_JOG_LEFT));
  OK(ussrt_wait_exchange(bus, 1, 2000));
  OK(ussrt_wait_exchange(bus, 1, 2000));
  OK(ussrt_drive_read(bus, 1, &d));
  EXPECT(d.image.sent_stw1 == 0x067E, "jog left: %#x", d.image.sent_stw1);
  OK(ussrt_control_stop(c));
  OK(ussrt_control_run_hz(c, 10.0f));
  OK(ussrt_control_wait_state(c, 4, 5000));
  const uint16_t bad[2] = {0x007F, 0};
  EXPECT(ussrt_control_set_words(c, bad, 2) == USSRT_STATUS_INVALID_SAMPLE, "bit 10 clear");
  EXPECT(ussrt_control_set_words(c, bad, 1) == USSRT_STATUS_INVALID_SAMPLE, "one word");
  OK(ussrt_control_keepalive(c));
  /* The loop's period: a quarter of the 100 ms watchdog, at most 20 ms. */
  uint32_t period_us = 0;
  OK(ussrt_control_refresh_period(c, &period_us));
  EXPECT(period_us == 20000, "refresh period %u us", period_us);
  EXPECT(ussrt_control_refresh_period(c, NULL) == USSRT_STATUS_INVALID_ARGUMENT, "NULL period");

  /* An operator's coast: the next call is the latch, with its reason and command. */
  const uint64_t before_coast = ussrt_monotonic_ns();
  OK(ussrt_stop_drive(bus, 1, 2));
  UssrtStatus s;
  do {
    OK(ussrt_wait_exchange(bus, 1, 1000));
    s = ussrt_control_keepalive(c);
  } while (s == USSRT_STATUS_OK);
  EXPECT(s == USSRT_STATUS_TRIPPED, "tripped, got %d", (int)s);
  EXPECT(info().latch_reason == USS_LATCH_REASON_OVERRIDE, "override %u", info().latch_reason);
  EXPECT(info().latch_command == USS_STOP_COMMAND_OFF2, "OFF2 %u", info().latch_command);
  EXPECT(info().latched_by_pid != 0, "the operator's pid");
  EXPECT(strstr(ussrt_last_error(), "an operator sent OFF2") != NULL, "message");
  EXPECT(ussrt_control_run_hz(c, 10.0f) == USSRT_STATUS_TRIPPED, "every call until re-armed");
  EXPECT(ussrt_control_check(c, &d) == USSRT_STATUS_TRIPPED && d.image.sent_stw1 == 0x047C,
         "still coasting: %#x", d.image.sent_stw1);
  EXPECT(ussrt_stop_drive(bus, 1, 7) == USSRT_STATUS_INVALID_ARGUMENT, "stop command 7");
  /* A re-arm asked for before the coast does not clear it: TRIPPED, the coast stays. */
  EXPECT(ussrt_control_rearm_at(c, before_coast, NULL) == USSRT_STATUS_TRIPPED,
         "a re-arm asked before the coast");
  EXPECT(ussrt_control_check(c, &d) == USSRT_STATUS_TRIPPED && d.image.sent_stw1 == 0x047C,
         "still coasting after it: %#x", d.image.sent_stw1);
  OK(ussrt_control_rearm_at(c, ussrt_monotonic_ns(), NULL));
  OK(ussrt_control_run_hz(c, 10.0f));

  /* A stall of this program: no call for 3 watchdog times is a trip, not a fresh start. */
  sleep_ms(300);
  s = ussrt_control_run_hz(c, 10.0f);
  EXPECT(s == USSRT_STATUS_TRIPPED || s == USSRT_STATUS_STALLED, "a gap trips: %d", (int)s);
  /* Found by ussd or by the program itself: a stale latch with the drive's safe command. */
  EXPECT(info().latch_reason == USS_LATCH_REASON_STALE, "stale %u", info().latch_reason);
  EXPECT(info().latch_command == USS_STOP_COMMAND_OFF1, "its safe command %u",
         info().latch_command);
  OK(ussrt_drive_read(bus, 1, &d));
  EXPECT(d.live == 0 && d.image.latch_reason == USS_LATCH_REASON_STALE, "stale latch");
  OK(ussrt_control_rearm_at(c, ussrt_monotonic_ns(), NULL));
  OK(ussrt_control_stop(c));
  OK(ussrt_control_release(c));
  EXPECT(ussrt_control_run_hz(c, 1.0f) == USSRT_STATUS_RELEASED, "released");
  ussrt_control_close(c);
  ussrt_control_close(NULL);
  OK(ussrt_drive_read(bus, 1, &d));
  EXPECT(d.image.latch_reason == USS_LATCH_REASON_RELEASED, "released %u",
         d.image.latch_reason);

  uint32_t reached = 0;
  OK(ussrt_stop_all(bus, 3, &reached));
  EXPECT(reached == 0x6, "stop all: %#x", reached);
  /* The stop confirmed as the drive's image shows it: the override and the word that went out. */
  UssrtDrive stopped;
  OK(ussrt_wait_stopped(bus, 1, 3, 0, &stopped));
  EXPECT(stopped.image.sent_stw1 == 0x047A && stopped.live == 0, "quick stop confirmed: %#x",
         stopped.image.sent_stw1);
  EXPECT(stopped.image.latch_reason == USS_LATCH_REASON_OVERRIDE, "override %u",
         stopped.image.latch_reason);
  OK(ussrt_wait_stopped(bus, 2, 1, 2000, NULL)); /* OFF3 is at least as strong as OFF1 */
  EXPECT(ussrt_wait_stopped(bus, 1, 9, 0, NULL) == USSRT_STATUS_INVALID_ARGUMENT,
         "stop command 9");
  /* What the drive says a parameter is: P1120 (ramp-up time) a settable float with limits; a
     parameter it does not have is its refusal. */
  UssrtDescription described;
  OK(ussrt_param_describe(bus, 2, "P1120", &described));
  EXPECT(described.data_type == 8 && described.read_only == 0, "P1120: type %u read-only %u",
         described.data_type, described.read_only);
  EXPECT(described.has_elements && described.has_min && described.has_max &&
             described.max > described.min,
         "P1120: elements %u limits %g..%g", described.elements, described.min, described.max);
  EXPECT(ussrt_param_describe(bus, 2, "P0999", &described) == USSRT_STATUS_DRIVE_ERROR,
         "P0999 described");
  EXPECT(info().drive_error == 0, "error 0 (no such parameter): %u", info().drive_error);
  EXPECT(ussrt_param_describe(bus, 2, "P1120", NULL) == USSRT_STATUS_INVALID_ARGUMENT,
         "NULL description");
  /* Guided commissioning: a value the drive refuses leaves quick commissioning (P0010 back to
     0); the rating plate then goes in and P3900 = 3 ends it; a factory reset brings P0304 back. */
  const char *params[] = {"P0304", "P0305"};
  const char *beyond[] = {"400", "20000"};
  const char *plate[] = {"400", "1.9"};
  EXPECT(ussrt_param_quick_commission(bus, 2, params, plate, 2, 3, 0) == USSRT_STATUS_REFUSED,
         "the end of quick commissioning only as unsafe");
  EXPECT(ussrt_param_quick_commission(bus, 2, params, beyond, 2, 3, USSRT_WRITE_UNSAFE) !=
             USSRT_STATUS_OK,
         "P0305 = 20000 A is beyond its limits");
  OK(ussrt_param_read(bus, 2, "P0010", &v));
  EXPECT(v.value == 0, "out of quick commissioning: %g", v.value);
  EXPECT(ussrt_param_quick_commission(bus, 2, params, plate, 2, 7, USSRT_WRITE_UNSAFE) ==
             USSRT_STATUS_VALUE,
         "P3900 = 7");
  EXPECT(ussrt_param_quick_commission(bus, 2, NULL, NULL, 2, 3, USSRT_WRITE_UNSAFE) ==
             USSRT_STATUS_INVALID_ARGUMENT,
         "NULL arrays");
  OK(ussrt_param_quick_commission(bus, 2, params, plate, 2, 3,
                                  USSRT_WRITE_UNSAFE | USSRT_WRITE_FORCE));
  OK(ussrt_param_read(bus, 2, "P0304", &v));
  EXPECT(v.value == 400, "P0304 %g", v.value);
  OK(ussrt_param_read(bus, 2, "P3900", &v));
  EXPECT(v.value == 0, "P3900 done: %g", v.value);
  EXPECT(ussrt_param_factory_reset(bus, 2, USSRT_WRITE_EEPROM) == USSRT_STATUS_INVALID_ARGUMENT,
         "a reset takes only USSRT_WRITE_UNSAFE and USSRT_WRITE_FORCE");
  EXPECT(ussrt_param_factory_reset(bus, 2, USSRT_WRITE_FORCE) == USSRT_STATUS_REFUSED,
         "a reset only as unsafe");
  OK(ussrt_param_factory_reset(bus, 2, USSRT_WRITE_UNSAFE | USSRT_WRITE_FORCE));
  OK(ussrt_param_read(bus, 2, "P0304", &v));
  EXPECT(v.value != 400, "factory's P0304 again: %g", v.value);

  ussrt_bus_close(bus);
  ussrt_bus_close(NULL);
  printf("abi_check: all %d checks passed (libussrt %s)\n", checks, ussrt_version());
  return 0;
}
