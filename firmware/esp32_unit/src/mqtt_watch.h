// What PubSubClient 2.8 reads but ignores, watched byte by byte as it reads them: a SUBACK that
// refuses a subscription (it never looks at SUBACKs, so its subscribe() only says "written"),
// and a QoS 1 PUBLISH too large for its buffer, which it drops without the PUBACK the broker
// then waits for (holding one of its in-flight slots for this device until the session ends).
#pragma once

#include <cstddef>
#include <cstdint>

namespace gf {

class InboundWatch {
 public:
  // `bufferBytes`: PubSubClient's buffer; it drops a packet whose whole length exceeds it.
  explicit InboundWatch(size_t bufferBytes) : bufferBytes_(bufferBytes) {}
  // A new connection: the stream starts at a packet boundary again.
  void reset();
  // One byte from the broker, in order.
  void feed(uint8_t byte);
  // A SUBACK of this connection refused a subscription (return code 0x80).
  bool refused() const { return refused_; }
  // The packet id of a QoS 1 PUBLISH just read whole that PubSubClient dropped; true once.
  bool takePuback(uint16_t& packetId);
  // Messages dropped for their size since start (all connections).
  uint32_t dropped() const { return dropped_; }

 private:
  void packetDone();

  enum class State : uint8_t { Header, Length, Body };
  size_t bufferBytes_;
  State state_ = State::Header;
  uint8_t header_ = 0;
  uint32_t remaining_ = 0;  // the packet's remaining length
  uint32_t multiplier_ = 1;
  uint32_t lengthBytes_ = 0;
  uint32_t pos_ = 0;  // bytes of the body read so far
  uint16_t topicLength_ = 0;
  uint16_t packetId_ = 0;
  bool refused_ = false;
  bool pubackDue_ = false;
  uint16_t pubackId_ = 0;
  uint32_t dropped_ = 0;
};

}  // namespace gf
