#include "mqtt_watch.h"

namespace gf {
namespace {
constexpr uint8_t kPublish = 3;
constexpr uint8_t kSuback = 9;
constexpr uint8_t kSubackFailure = 0x80;
}  // namespace

void InboundWatch::reset() {
  state_ = State::Header;
  refused_ = false;
  pubackDue_ = false;
}

void InboundWatch::feed(uint8_t byte) {
  switch (state_) {
    case State::Header:
      header_ = byte;
      remaining_ = 0;
      multiplier_ = 1;
      lengthBytes_ = 0;
      state_ = State::Length;
      return;
    case State::Length:
      remaining_ += (byte & 0x7Fu) * multiplier_;
      multiplier_ *= 128;
      ++lengthBytes_;
      if ((byte & 0x80u) != 0 && lengthBytes_ < 4) return;
      pos_ = 0;
      topicLength_ = 0;
      packetId_ = 0;
      if (remaining_ == 0) {
        packetDone();
      } else {
        state_ = State::Body;
      }
      return;
    case State::Body: {
      const uint8_t type = header_ >> 4;
      if (type == kSuback && pos_ >= 2 && byte == kSubackFailure) refused_ = true;
      if (type == kPublish) {
        // Topic length (2 bytes), topic, then the packet id (2 bytes) when QoS > 0.
        if (pos_ < 2) topicLength_ = static_cast<uint16_t>((topicLength_ << 8) | byte);
        const uint32_t idAt = 2u + topicLength_;
        if (pos_ >= 2 && (pos_ == idAt || pos_ == idAt + 1)) {
          packetId_ = static_cast<uint16_t>((packetId_ << 8) | byte);
        }
      }
      if (++pos_ == remaining_) packetDone();
      return;
    }
  }
}

void InboundWatch::packetDone() {
  state_ = State::Header;
  if ((header_ >> 4) != kPublish) return;
  // PubSubClient keeps a packet only when all of it (header included) fits its buffer.
  const uint32_t whole = 1 + lengthBytes_ + remaining_;
  if (whole <= bufferBytes_) return;
  ++dropped_;
  const uint8_t qos = (header_ >> 1) & 0x03u;
  if (qos == 1) {
    pubackDue_ = true;
    pubackId_ = packetId_;
  }
}

bool InboundWatch::takePuback(uint16_t& packetId) {
  if (!pubackDue_) return false;
  pubackDue_ = false;
  packetId = pubackId_;
  return true;
}

}  // namespace gf
