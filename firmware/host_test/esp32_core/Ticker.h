// Host stand-in for arduino-esp32's Ticker (a periodic esp_timer callback): a thread calling the
// callback every period until detached.
#pragma once

#include <atomic>
#include <cstdint>
#include <thread>

class Ticker {
 public:
  Ticker() = default;
  ~Ticker() { detach(); }
  Ticker(const Ticker&) = delete;
  Ticker& operator=(const Ticker&) = delete;
  // arduino-esp32 2.x takes `void (*)()`, 3.x a std::function<void()>: a function converts to both.
  void attach_ms(uint32_t milliseconds, void (*callback)());
  void detach();

 private:
  std::thread thread_;
  std::atomic<bool> running_{false};
};
