// Host-only stand-in for arduino-esp32's Ticker (signatures only): records the callback, which
// a test calls itself.
#pragma once

#include <cstdint>

class Ticker {
 public:
  void attach_ms(uint32_t milliseconds, void (*callback)()) {
    periodMs = milliseconds;
    fire = callback;
  }
  void detach() { fire = nullptr; }
  uint32_t periodMs = 0;
  void (*fire)() = nullptr;
};
