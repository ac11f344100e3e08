// Button debouncing, reconnect back-off and the pending stop: time-driven logic with no clock of
// its own (every call gets `nowMs`, a wrapping millisecond counter like Arduino's millis()).
#pragma once

#include <cstdint>

namespace gf {

// Turns the interrupt's edge flag and the pin level into exactly one press per physical press.
// A press counts on the first edge (so a press shorter than one loop is never lost); then the
// button must stay released, with no edges, for `quietMs` before the next press can count.
class Debouncer {
 public:
  explicit Debouncer(uint32_t quietMs) : quietMs_(quietMs) {}
  // `edge`: the interrupt fired since the last call; `pressed`: the pin reads pressed now.
  bool update(bool edge, bool pressed, uint32_t nowMs);

 private:
  uint32_t quietMs_;
  bool armed_ = true;
  uint32_t lastActiveMs_ = 0;
};

// Exponential back-off between connection attempts: initial, doubled each failure, capped.
class Backoff {
 public:
  Backoff(uint32_t initialMs, uint32_t maxMs) : initialMs_(initialMs), maxMs_(maxMs), nextMs_(initialMs) {}
  // The wait before the next attempt; each call doubles the following one up to the cap.
  uint32_t next();
  void reset() { nextMs_ = initialMs_; }
  uint32_t peek() const { return nextMs_; }

 private:
  uint32_t initialMs_;
  uint32_t maxMs_;
  uint32_t nextMs_;
};

// A stop press that is not done until the device has seen its own `engaged` come back from the
// broker. PubSubClient publishes QoS 0 only, so the device publishes retained to its own
// `devices/<id>/stop`, which it subscribes to, and publishes again (same payload, idempotent)
// after each reconnect and every `retryMs` until it sees it come back there.
class PendingStop {
 public:
  explicit PendingStop(uint32_t retryMs) : retryMs_(retryMs) {}
  void press() { pending_ = true; }
  bool pending() const { return pending_; }
  // Whether to publish now (connected is the caller's business).
  bool due(uint32_t nowMs) const;
  void sent(uint32_t nowMs);
  // The broker lost us: the next connection sends at once.
  void connectionLost() { sentThisSession_ = false; }
  // Our own `engaged` came back: the press is done.
  void confirmed() {
    pending_ = false;
    sentThisSession_ = false;
  }

 private:
  uint32_t retryMs_;
  bool pending_ = false;
  bool sentThisSession_ = false;
  uint32_t lastSentMs_ = 0;
};

}  // namespace gf
