// The brokers the device may connect to (config.h's GF_MQTT_BROKERS: one, or the nodes of a
// cluster) and which of them it is on: it moves to the next when its broker is lost or an attempt
// fails, and backs off only once a whole round of the list has failed.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace gf {

struct Broker {
  Broker() = default;
  Broker(const std::string& h, uint16_t p) : host(h), port(p) {}
  std::string name() const { return host + ":" + std::to_string(port); }

  std::string host;
  uint16_t port = 0;
};

// The default ports: MQTT over TLS, and over plain TCP.
constexpr uint16_t kMqttTlsPort = 8883;
constexpr uint16_t kMqttPort = 1883;

// Parse a comma-separated list of brokers into `out`: each `host:port`, `mqtt://host:port`
// (plain TCP) or `mqtts://host:port` (TLS), the port defaulting to 8883 with TLS and 1883
// without. `tls`: the device connects with TLS (GF_MQTT_CA_PEM given), to every broker of the
// list. Empty when usable, else what is wrong, naming the item (and `out` is left empty).
std::string parseBrokers(const std::string& text, bool tls, std::vector<Broker>& out);

// The brokers of a list, for messages: "a:1883, b:1883".
std::string brokerNames(const std::vector<Broker>& brokers);

// Which broker of a list of `count` the next attempt goes to.
class BrokerRotation {
 public:
  explicit BrokerRotation(size_t count) : count_(count == 0 ? 1 : count) {}
  size_t current() const { return index_; }
  // An attempt on the current broker failed: move to the next. True when that one is to be
  // tried at once; false when every broker of the list has failed since the last session
  // (or since the last round): the device then backs off before the next round.
  bool failed();
  // The session on the current broker was lost: move to the next, and a new round begins.
  void lost();
  // Connected: a later loss starts a new round.
  void connected() { failures_ = 0; }

 private:
  size_t count_;
  size_t index_ = 0;
  size_t failures_ = 0;  // failed attempts in this round
};

}  // namespace gf
