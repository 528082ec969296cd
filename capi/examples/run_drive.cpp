/*
 * run_drive (C++): the same control loop as run_drive.c on the RAII wrapper ussrt.hpp. The
 * controller hands the drive back when it goes out of scope, whatever happened.
 *
 *   c++ -std=c++17 run_drive.cpp $(pkg-config --cflags --libs ussrt) -o run_drive_cpp
 *   ./run_drive_cpp bus0 1 10 2
 */
#include <chrono>
#include <cstdio>
#include <cstdlib>

#include <ussrt.hpp>

int main(int argc, char **argv) {
  if (argc != 5) {
    std::fprintf(stderr, "usage: run_drive_cpp BUS DRIVE HZ SECONDS\n");
    return 2;
  }
  const uint8_t address = static_cast<uint8_t>(std::atoi(argv[2]));
  const float hz = static_cast<float>(std::atof(argv[3]));
  const std::chrono::duration<double> run_for(std::atof(argv[4]));
  try {
    ussrt::Bus bus(argv[1]);
    std::printf("%s\n", bus.read(address, "P1082").text);
    ussrt::Controller drive(bus, address);
    // The re-arm was asked for when this program started: a stop while it starts stays.
    drive.rearm(ussrt::process_start_ns());
    std::printf("drive %u: re-armed; running towards %.1f Hz\n", address, hz);
    const auto start = std::chrono::steady_clock::now();
    bool reached = false;
    while (std::chrono::steady_clock::now() - start < run_for) {
      drive.run_hz(hz);  // the loop's own call: the watchdog refresh
      bus.wait_exchange(address, 500);
      const UssrtDrive d = drive.check_drive();
      // Reached: the drive's actual value is the setpoint that went out.
      if (!reached && d.state == 4 && d.image.hiw == d.image.sent_setpoint) {
        reached = true;
        std::printf("drive %u: S4 at %.2f Hz\n", address, d.actual_hz);
      }
    }
    drive.stop();
    drive.wait_state(2, 30000);
    drive.release();
    std::printf("drive %u: stopped (OFF1, S2) and released\n", address);
  } catch (const ussrt::Error &e) {
    std::fprintf(stderr, "run_drive_cpp: %s (status %d, latch reason %u)\n", e.what(),
                 static_cast<int>(e.status()), e.info().latch_reason);
    return 1;
  }
  return 0;
}
