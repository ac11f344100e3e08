// InboundWatch: what PubSubClient 2.8 reads but ignores (SUBACK refusals, oversized messages).
#include <doctest/doctest.h>

#include <cstdint>
#include <string>
#include <vector>

#include "../esp32_unit/src/diagnostics.h"
#include "../esp32_unit/src/mqtt_watch.h"

namespace {
std::vector<uint8_t> remainingLength(size_t n) {
  std::vector<uint8_t> out;
  do {
    uint8_t digit = n % 128;
    n /= 128;
    if (n > 0) digit |= 0x80;
    out.push_back(digit);
  } while (n > 0);
  return out;
}

// A PUBLISH as a broker sends it: QoS 0 or 1 (then with `id`), `payloadBytes` of 'x'.
std::vector<uint8_t> publish(const std::string& topic, size_t payloadBytes, int qos, uint16_t id) {
  std::vector<uint8_t> body = {uint8_t(topic.size() >> 8), uint8_t(topic.size())};
  body.insert(body.end(), topic.begin(), topic.end());
  if (qos == 1) {
    body.push_back(uint8_t(id >> 8));
    body.push_back(uint8_t(id));
  }
  body.insert(body.end(), payloadBytes, 'x');
  std::vector<uint8_t> packet = {uint8_t(0x30 | (qos << 1))};
  const auto len = remainingLength(body.size());
  packet.insert(packet.end(), len.begin(), len.end());
  packet.insert(packet.end(), body.begin(), body.end());
  return packet;
}

void feed(gf::InboundWatch& w, const std::vector<uint8_t>& bytes) {
  for (uint8_t b : bytes) w.feed(b);
}
}  // namespace

TEST_CASE("a SUBACK refusing a subscription is noticed; granted ones are not") {
  gf::InboundWatch w(768);
  feed(w, {0x20, 0x02, 0x00, 0x00});              // CONNACK
  feed(w, {0x90, 0x03, 0x00, 0x01, 0x00});        // SUBACK granted QoS 0
  feed(w, {0x90, 0x03, 0x00, 0x02, 0x01});        // granted QoS 1
  CHECK_FALSE(w.refused());
  feed(w, {0x90, 0x03, 0x00, 0x03, 0x80});        // refused
  CHECK(w.refused());
  w.reset();  // a new connection starts clean
  CHECK_FALSE(w.refused());
}

TEST_CASE("an oversized QoS 1 message is acknowledged for PubSubClient; others are not") {
  gf::InboundWatch w(768);
  uint16_t id = 0;
  const std::string topic = "gridfleet/v1/fleet/estop";
  // Fits exactly: 1 + 2 length bytes + 2 + topic + 2 + payload == 768.
  const size_t fits = 768 - 7 - topic.size();
  auto ok = publish(topic, fits, 1, 7);
  REQUIRE(ok.size() == 768);
  feed(w, ok);
  CHECK_FALSE(w.takePuback(id));
  CHECK(w.dropped() == 0);
  feed(w, publish(topic, fits + 1, 1, 0x1234));
  REQUIRE(w.takePuback(id));
  CHECK(id == 0x1234);
  CHECK_FALSE(w.takePuback(id));  // once
  CHECK(w.dropped() == 1);
  feed(w, publish(topic, 5000, 0, 0));  // QoS 0: dropped, nothing to acknowledge
  CHECK_FALSE(w.takePuback(id));
  CHECK(w.dropped() == 2);
  // The stream stays in step: a refusal after the big ones is still seen.
  feed(w, {0x90, 0x03, 0x00, 0x04, 0x80});
  CHECK(w.refused());
  feed(w, {0xD0, 0x00});  // PINGRESP
  feed(w, publish("t", 20000, 1, 9));
  REQUIRE(w.takePuback(id));
  CHECK(id == 9);
}

TEST_CASE("connection failures are said in words") {
  CHECK(gf::mqttStateWords(4).find("user name or password") != std::string::npos);
  CHECK(gf::mqttStateWords(5).find("does not authorise") != std::string::npos);
  CHECK(gf::mqttStateWords(-4).find("did not answer") != std::string::npos);
  CHECK(gf::mqttStateWords(-2).find("no network connection") != std::string::npos);
  CHECK(gf::mqttStateWords(42) == "PubSubClient state 42");
  CHECK(gf::wifiStatusWords(1).find("not in range") != std::string::npos);
  CHECK(gf::wifiStatusWords(4).find("wrong GF_WIFI_PASSWORD") != std::string::npos);
  CHECK(gf::wifiStatusWords(3).find("connected") != std::string::npos);
}
