/*
 * scan_check: ussrt_scan against uss-sim over a pty (started by tests/tests/capi.rs): the
 * drives of the line with their layouts, family and firmware; a room too small and a device
 * that does not exist are said by their statuses. Exits 1 at the first wrong answer.
 *
 *   scan_check PTY    (19200 baud: drive 3 pkw=4,pzd=2; drive 5 pkw=127,pzd=6,g120)
 */
#include <stdio.h>
#include <stdlib.h>

#include <ussrt.h>

static int checks;

#define EXPECT(cond, ...)                                                                  \
  do {                                                                                     \
    checks++;                                                                              \
    if (!(cond)) {                                                                         \
      fprintf(stderr, "scan_check:%d: %s: ", __LINE__, #cond);                             \
      fprintf(stderr, __VA_ARGS__);                                                        \
      fprintf(stderr, " (last error: %s)\n", ussrt_last_error());                          \
      exit(1);                                                                             \
    }                                                                                      \
  } while (0)

int main(int argc, char **argv) {
  if (argc != 2) {
    fprintf(stderr, "usage: scan_check PTY\n");
    return 2;
  }
  const uint32_t bauds[] = {19200};
  const uint8_t addresses[] = {2, 3, 4, 5};
  UssrtScanned found[4];
  size_t count = 0;
  UssrtStatus s = ussrt_scan(argv[1], bauds, 1, addresses, 4, 4, found, 4, &count);
  EXPECT(s == USSRT_STATUS_OK, "status %d", (int)s);
  EXPECT(count == 2, "%zu found", count);
  EXPECT(found[0].address == 3 && found[0].pkw == 4 && found[0].pzd == 2, "drive 3: %u %u %u",
         found[0].address, found[0].pkw, found[0].pzd);
  EXPECT(found[0].has_zsw1 && found[0].zsw1 == 0xBB31, "ZSW1 %#x", found[0].zsw1);
  EXPECT(found[0].family == USS_DRIVE_FAMILY_MICROMASTER4 && found[0].firmware == 209 &&
             found[0].sure == 1,
         "family %u firmware %u sure %u", found[0].family, found[0].firmware, found[0].sure);
  EXPECT(found[1].address == 5 && found[1].pkw == 127 && found[1].pzd == 6 &&
             found[1].family == USS_DRIVE_FAMILY_G120 && found[1].firmware == 470,
         "drive 5: pkw %u pzd %u family %u firmware %u", found[1].pkw, found[1].pzd,
         found[1].family, found[1].firmware);
  /* Room for one: the first written, the count of all, INVALID_ARGUMENT. */
  UssrtScanned one[1];
  s = ussrt_scan(argv[1], bauds, 1, addresses, 4, 4, one, 1, &count);
  EXPECT(s == USSRT_STATUS_INVALID_ARGUMENT && count == 2 && one[0].address == 3, "status %d",
         (int)s);
  /* A device that does not exist: DEVICE, with the device's words. */
  s = ussrt_scan("/dev/uss-no-such-tty", bauds, 1, addresses, 1, 1, found, 4, &count);
  EXPECT(s == USSRT_STATUS_DEVICE, "status %d", (int)s);
  EXPECT(ussrt_last_error()[0] != '\0', "no message");
  printf("scan_check: all %d checks passed\n", checks);
  return 0;
}
