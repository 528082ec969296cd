// The C++ front-end of the safety conformance suite (tests/tests/conformance.rs,
// docs/SAFETY.md): a controller of the RAII wrapper ussrt.hpp driven line by line from stdin.
// The same protocol as conformance.c: a command per line ('&' first: on a thread of its own),
// answered by "<< ok" or "<< err KIND MESSAGE" ("<&" for a thread's).
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "ussrt.hpp"

namespace {

std::mutex out_lock;

void answer(const char *tag, const ussrt::Error *e) {
  std::lock_guard<std::mutex> held(out_lock);
  if (e == nullptr) {
    std::cout << tag << " ok" << std::endl;
  } else {
    std::cout << tag << " err " << ussrt_status_name(static_cast<int32_t>(e->status())) << " "
              << e->what() << std::endl;
  }
}

void call(ussrt::Controller &c, const std::string &line, const char *tag) {
  std::istringstream words(line);
  std::string cmd;
  words >> cmd;
  try {
    if (cmd == "keepalive") {
      c.keepalive();
    } else if (cmd == "enable") {
      c.enable();
    } else if (cmd == "stop") {
      c.stop();
    } else if (cmd == "coast") {
      c.coast();
    } else if (cmd == "quick_stop") {
      c.quick_stop();
    } else if (cmd == "rearm") {
      // Asked for when the line arrives; "rearm MS" calls MS later.
      const uint64_t asked = ussrt::monotonic_ns();
      unsigned ms = 0;
      words >> ms;
      std::this_thread::sleep_for(std::chrono::milliseconds(ms));
      c.rearm(asked);
    } else if (cmd == "check") {
      c.check_drive();
    } else if (cmd == "run") {
      float hz = 0;
      words >> hz;
      c.run_hz(hz);
    } else if (cmd == "acknowledge") {
      unsigned ms = 0;
      words >> ms;
      c.acknowledge_fault(ms);
    } else if (cmd == "wait_state") {
      unsigned state = 0, ms = 0;
      words >> state >> ms;
      c.wait_state(static_cast<uint8_t>(state), ms);
    } else if (cmd == "set_words") {
      std::vector<uint16_t> w;
      std::string word;
      while (words >> word) w.push_back(static_cast<uint16_t>(std::stoul(word, nullptr, 0)));
      c.set_words(w.data(), w.size());
    } else if (cmd == "release") {
      c.release();
    } else {
      std::cerr << "conformance: unknown command " << cmd << std::endl;
      std::exit(2);
    }
    answer(tag, nullptr);
  } catch (const ussrt::Error &e) {
    answer(tag, &e);
  }
}

} // namespace

int main() {
  std::unique_ptr<ussrt::Bus> bus;
  std::unique_ptr<ussrt::Controller> controller;
  std::vector<std::thread> threads;
  std::string line;
  while (std::getline(std::cin, line)) {
    if (line.rfind("open ", 0) == 0) {
      std::istringstream words(line.substr(5));
      std::string name;
      unsigned address = 0;
      words >> name >> address;
      try {
        bus = std::make_unique<ussrt::Bus>(name);
        controller = std::make_unique<ussrt::Controller>(*bus, static_cast<uint8_t>(address));
        answer("<<", nullptr);
      } catch (const ussrt::Error &e) {
        answer("<<", &e);
      }
    } else if (line.rfind("exit", 0) == 0) {
      break;
    } else if (!line.empty() && line[0] == '&') {
      threads.emplace_back(call, std::ref(*controller), line.substr(1), "<&");
    } else {
      call(*controller, line, "<<");
    }
  }
  for (auto &t : threads) t.join();
  controller.reset(); // hands the drive back
  return 0;
}
