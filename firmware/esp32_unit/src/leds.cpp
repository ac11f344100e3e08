#include "leds.h"

namespace gf {

Leds ledsFor(Direction direction, bool stop, bool online, uint32_t nowMs) {
  Leds out;
  if (stop) {
    bool on = (nowMs / kBlinkHalfPeriodMs) % 2 == 0;
    out.n = out.e = out.s = out.w = on;
    return out;
  }
  if (!online) {
    switch ((nowMs / kChaseStepMs) % 4) {
      case 0: out.n = true; break;
      case 1: out.e = true; break;
      case 2: out.s = true; break;
      default: out.w = true; break;
    }
    return out;
  }
  switch (direction) {
    case Direction::N: out.n = true; break;
    case Direction::E: out.e = true; break;
    case Direction::S: out.s = true; break;
    case Direction::W: out.w = true; break;
    case Direction::None: break;
  }
  return out;
}

}  // namespace gf
