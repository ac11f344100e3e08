// What the four direction LEDs show: the direction, the stop pattern, or the offline pattern.
#pragma once

#include <cstdint>

#include "protocol.h"

namespace gf {

struct Leds {
  bool n = false;
  bool e = false;
  bool s = false;
  bool w = false;

  int count() const { return int(n) + int(e) + int(s) + int(w); }
  bool operator==(const Leds& o) const { return n == o.n && e == o.e && s == o.s && w == o.w; }
  bool operator!=(const Leds& o) const { return !(*this == o); }
};

constexpr uint32_t kBlinkHalfPeriodMs = 250;  // stop: all four blink at 2 Hz
constexpr uint32_t kChaseStepMs = 250;        // offline: one LED runs round N E S W

// The stop pattern wins over everything (also while offline, so a pressed stop stays visible);
// offline comes next, because a direction from a lost broker is stale; then the direction itself.
Leds ledsFor(Direction direction, bool stop, bool online, uint32_t nowMs);

}  // namespace gf
