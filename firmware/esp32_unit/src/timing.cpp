#include "timing.h"

namespace gf {

bool Debouncer::update(bool edge, bool pressed, uint32_t nowMs) {
  if (armed_) {
    if (edge || pressed) {
      armed_ = false;
      lastActiveMs_ = nowMs;
      return true;
    }
    return false;
  }
  // Bounces of the press and of the release keep restarting the quiet period.
  if (edge || pressed) {
    lastActiveMs_ = nowMs;
  } else if (uint32_t(nowMs - lastActiveMs_) >= quietMs_) {
    armed_ = true;
  }
  return false;
}

uint32_t Backoff::next() {
  uint32_t wait = nextMs_;
  nextMs_ = nextMs_ >= maxMs_ / 2 ? maxMs_ : nextMs_ * 2;
  return wait;
}

bool PendingStop::due(uint32_t nowMs) const {
  if (!pending_) return false;
  return !sentThisSession_ || uint32_t(nowMs - lastSentMs_) >= retryMs_;
}

void PendingStop::sent(uint32_t nowMs) {
  sentThisSession_ = true;
  lastSentMs_ = nowMs;
}

}  // namespace gf
