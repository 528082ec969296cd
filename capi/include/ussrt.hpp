/*
 * ussrt.hpp: a C++ wrapper (RAII, exceptions) over ussrt.h, header only.
 *
 *   ussrt::Bus bus("line1");                  // throws ussrt::Error (NOT_RUNNING, ...)
 *   ussrt::Controller drive(bus, 3);          // exclusive control; released when it goes
 *   drive.rearm(ussrt::process_start_ns());   // OFF1 naming a latch older than the ask, then ON
 *   drive.run_hz(25.0f);
 *   for (;;) { bus.wait_exchange(3, 500); drive.keepalive(); ... }
 *
 * Every failure is an ussrt::Error with the status, the message (what to do) and the details
 * (the latch, the drive's error number). Objects are movable, not copyable; a moved-from
 * object holds nothing.
 */
#ifndef USSRT_HPP
#define USSRT_HPP

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>
#include <utility>

#include "ussrt.h"

namespace ussrt {

/// A failed call: status(), what() (the library's message), info() (latch, drive error).
class Error : public std::runtime_error {
public:
  Error(UssrtStatus status, const char *message)
      : std::runtime_error(message), status_(status), info_() {
    ussrt_last_error_info(&info_);
  }
  UssrtStatus status() const noexcept { return status_; }
  const UssrtErrorInfo &info() const noexcept { return info_; }

private:
  UssrtStatus status_;
  UssrtErrorInfo info_;
};

/// Throws the calling thread's last error unless `status` is OK.
inline void check(UssrtStatus status) {
  if (status != USSRT_STATUS_OK) {
    throw Error(status, ussrt_last_error());
  }
}

/// CLOCK_MONOTONIC now, ns: the clock of a re-arm's asked_ns.
inline uint64_t monotonic_ns() noexcept { return ussrt_monotonic_ns(); }

/// When this process started (CLOCK_MONOTONIC ns, rounded down to 10 ms): the asked_ns of a
/// program that re-arms once it is set up.
inline uint64_t process_start_ns() {
  uint64_t started = 0;
  check(ussrt_process_start_ns(&started));
  return started;
}

/// An open bus; closed when it goes.
class Bus {
public:
  explicit Bus(const std::string &name) : bus_(nullptr) {
    check(ussrt_bus_open(name.c_str(), &bus_));
  }
  ~Bus() { ussrt_bus_close(bus_); }
  Bus(const Bus &) = delete;
  Bus &operator=(const Bus &) = delete;
  Bus(Bus &&other) noexcept : bus_(std::exchange(other.bus_, nullptr)) {}
  Bus &operator=(Bus &&other) noexcept {
    std::swap(bus_, other.bus_);
    return *this;
  }

  /// The drive's latest image and what it means (stale = 1: not the drive as it is now).
  UssrtDrive drive(uint8_t address) const {
    UssrtDrive d;
    check(ussrt_drive_read(bus_, address, &d));
    return d;
  }
  /// Throws USSD_GONE, USSD_STOPPED or LINE_DOWN unless ussd serves the bus now.
  void health() const { check(ussrt_bus_health(bus_)); }
  /// The bus's status as ussd publishes it (counters, line state, exchange times).
  UssBusStatus status() const {
    UssBusStatus s;
    check(ussrt_bus_status(bus_, &s));
    return s;
  }
  /// The drive's diagnostics as ussd publishes them (counters, configuration, link).
  UssDriveDiag diag(uint8_t address) const {
    UssDriveDiag d;
    check(ussrt_drive_diag(bus_, address, &d));
    return d;
  }
  /// Waits for the drive's next exchange (throws TIMEOUT after timeout_ms).
  void wait_exchange(uint8_t address, uint32_t timeout_ms) const {
    check(ussrt_wait_exchange(bus_, address, timeout_ms));
  }
  /// A parameter in the manuals' notation ("P1082", "r0947[0]") as its own type.
  UssrtValue read(uint8_t address, const std::string &param) const {
    UssrtValue v;
    check(ussrt_param_read(bus_, address, param.c_str(), &v));
    return v;
  }
  /// Every element of an array parameter named without one ("r0947"), or the one named.
  std::vector<UssrtValue> read_elements(uint8_t address, const std::string &param) const {
    std::vector<UssrtValue> values(1);
    size_t count = 0;
    UssrtStatus s = ussrt_param_read_elements(bus_, address, param.c_str(), values.data(),
                                              values.size(), &count);
    if (s == USSRT_STATUS_INVALID_ARGUMENT && count > values.size()) {
      values.resize(count);
      s = ussrt_param_read_elements(bus_, address, param.c_str(), values.data(), values.size(),
                                    &count);
    }
    check(s);
    values.resize(count);
    return values;
  }
  /// Writes text converted to the parameter's type; returns what the drive holds.
  UssrtValue write(uint8_t address, const std::string &param, const std::string &value,
                   uint32_t flags = 0) const {
    UssrtValue v;
    check(ussrt_param_write(bus_, address, param.c_str(), value.c_str(), flags, &v));
    return v;
  }
  /// An operator's stop: 1 OFF1, 2 OFF2 (coast), 3 OFF3 (quick stop); latched.
  void stop(uint8_t address, uint8_t command = 1) const {
    check(ussrt_stop_drive(bus_, address, command));
  }
  const UssrtBus *get() const noexcept { return bus_; }

private:
  UssrtBus *bus_;
};

/// Exclusive control of one drive; the drive is handed back (released) when it goes.
class Controller {
public:
  Controller(const Bus &bus, uint8_t address) : c_(nullptr) {
    check(ussrt_control_open(bus.get(), address, &c_));
  }
  ~Controller() { ussrt_control_close(c_); }
  Controller(const Controller &) = delete;
  Controller &operator=(const Controller &) = delete;
  Controller(Controller &&other) noexcept : c_(std::exchange(other.c_, nullptr)) {}
  Controller &operator=(Controller &&other) noexcept {
    std::swap(c_, other.c_);
    return *this;
  }

  /// Acknowledges the latch and re-arms (OFF1 naming it); waits until the drive is live.
  /// asked_ns: when the deliberate act behind it happened (process_start_ns(), monotonic_ns()
  /// at the operator's button): a latch that began after it is not re-armed (TRIPPED).
  UssrtDrive rearm(uint64_t asked_ns) {
    UssrtDrive d;
    check(ussrt_control_rearm_at(c_, asked_ns, &d));
    return d;
  }
  /// The drive; throws TRIPPED when it latched since this controller acknowledged a latch.
  UssrtDrive check_drive() const {
    UssrtDrive d;
    check(ussrt_control_check(c_, &d));
    return d;
  }
  void keepalive() { check(ussrt_control_keepalive(c_)); }
  void enable() { check(ussrt_control_enable(c_)); }
  void run_hz(float hz) { check(ussrt_control_run_hz(c_, hz)); }
  void run_percent(float percent) { check(ussrt_control_run_percent(c_, percent)); }
  /// A new setpoint, the control word as it is.
  void set_hz(float hz) { check(ussrt_control_set_hz(c_, hz)); }
  /// Jogs while the calls keep coming; stop() ends it.
  void jog(UssrtJog direction) { check(ussrt_control_jog(c_, static_cast<uint8_t>(direction))); }
  void stop() { check(ussrt_control_stop(c_)); }
  void coast() { check(ussrt_control_coast(c_)); }
  void quick_stop() { check(ussrt_control_quick_stop(c_)); }
  void reverse(bool on) { check(ussrt_control_reverse(c_, on ? 1 : 0)); }
  void acknowledge_fault(uint32_t timeout_ms) {
    check(ussrt_control_acknowledge_fault(c_, timeout_ms));
  }
  /// Sends `count` PZD words as they are (STW1 first); INVALID_SAMPLE for words ussd refuses.
  void set_words(const uint16_t *words, size_t count) {
    check(ussrt_control_set_words(c_, words, count));
  }
  /// Waits for S1..S4 (1..4), refreshing the watchdog meanwhile.
  void wait_state(uint8_t state, uint32_t timeout_ms) {
    check(ussrt_control_wait_state(c_, state, timeout_ms));
  }
  /// Hands the drive back now (the destructor does it otherwise).
  void release() { check(ussrt_control_release(c_)); }

private:
  UssrtController *c_;
};

} // namespace ussrt

#endif
