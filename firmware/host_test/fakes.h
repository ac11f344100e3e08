// Test doubles for the Device's injected parts: a tiny in-memory broker, a link and a clock.
#pragma once

#include <map>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "../esp32_unit/src/device.h"

namespace gft {

class FakeClock : public gf::Clock {
 public:
  uint32_t nowMs() override { return now; }
  void advance(uint32_t ms) { now += ms; }
  uint32_t now = 1000;
};

class FakeLink : public gf::NetLink {
 public:
  bool up() override { return isUp; }
  void begin() override { ++begins; }
  std::string status() override { return isUp ? "up" : "wrong password"; }
  bool isUp = true;
  int begins = 0;
};

class FakeLog : public gf::Log {
 public:
  void line(const std::string& text) override { lines.push_back(text); }
  bool has(const std::string& part) const {
    for (const auto& l : lines) {
      if (l.find(part) != std::string::npos) return true;
    }
    return false;
  }
  std::vector<std::string> lines;
};

// Behaves like a broker with one client: keeps retained values, delivers to subscriptions on
// loop() (as PubSubClient does), and records what the device published. With a list of brokers
// it is a cluster: one store of retained values, nodes that can be down (`down`) one by one.
class FakeMqtt : public gf::MqttTransport {
 public:
  struct Msg {
    std::string topic;
    std::string payload;
    bool retained;
  };

  void setBroker(const gf::Broker& broker) override { target = broker.name(); }
  bool connect(const std::string& clientId, const std::string& willTopic,
               const std::string& willPayload) override {
    ++connectCalls;
    attempts.push_back(target);
    if (clock != nullptr) clock->advance(connectTakesMs);  // the attempt blocks
    // As PubSubClient does: while the old session looks open, true without a new CONNECT.
    if (isConnected) return true;
    if (!brokerUp || down.count(target)) return false;
    ++connectPackets;
    on = target;
    isConnected = true;
    refused = false;
    this->clientId = clientId;
    will = {willTopic, willPayload, true};
    subscriptions.clear();
    return true;
  }
  bool connected() override { return isConnected; }
  bool subscribe(const std::string& topic, uint8_t qos) override {
    if (!isConnected || failSubscribe) return false;
    // Written: PubSubClient says yes here, whatever the SUBACK will say.
    if (refuseTopics.count(topic)) {
      subackRefusals = true;
      return true;
    }
    subscriptions[topic] = qos;
    auto it = retained.find(topic);
    if (it != retained.end()) inbox.emplace_back(topic, it->second);
    return true;
  }
  bool refusedSubscription() override { return isConnected && refused; }
  std::string lastError() override { return error; }
  bool publish(const std::string& topic, const std::string& payload, bool isRetained) override {
    if (!isConnected) return false;
    published.push_back({topic, payload, isRetained});
    if (dropPublishes) return true;  // handed to the socket, lost on the way (QoS 0)
    route(topic, payload, isRetained);
    return true;
  }
  void loop() override {
    if (subackRefusals) refused = true;  // the SUBACK arrives
    subackRefusals = false;
    auto batch = std::move(inbox);
    inbox.clear();
    for (auto& [topic, payload] : batch) {
      if (device != nullptr) {
        device->onMessage(topic, reinterpret_cast<const uint8_t*>(payload.data()),
                          payload.size());
      }
    }
  }

  // Test side: another client publishes.
  void route(const std::string& topic, const std::string& payload, bool isRetained) {
    if (isRetained) retained[topic] = payload;
    if (isConnected && subscriptions.count(topic)) inbox.emplace_back(topic, payload);
  }
  // The node the device is on dies: its connection drops, and it refuses new ones.
  void kill(const std::string& broker) {
    down.insert(broker);
    if (on == broker) drop();
  }
  // The connection drops (or the device closes it without DISCONNECT): the broker publishes
  // the will.
  void drop() override {
    if (isConnected) ++drops;
    isConnected = false;
    inbox.clear();
    if (!will.topic.empty()) retained[will.topic] = will.payload;
  }
  int count(const std::string& topic, const std::string& payload) const {
    int n = 0;
    for (const auto& m : published) n += m.topic == topic && m.payload == payload;
    return n;
  }

  gf::Device* device = nullptr;
  FakeClock* clock = nullptr;
  uint32_t connectTakesMs = 0;
  bool brokerUp = true;
  std::string target;  // where the next connect() goes (setBroker)
  std::string on;  // the broker of the last session
  std::set<std::string> down;  // brokers of the list that are down
  std::vector<std::string> attempts;  // each connect()'s broker
  bool isConnected = false;
  bool dropPublishes = false;
  bool failSubscribe = false;
  std::set<std::string> refuseTopics;  // the broker's ACL says no: a refusing SUBACK
  bool subackRefusals = false;
  bool refused = false;
  std::string error = "broker down";
  int connectCalls = 0;
  int connectPackets = 0;  // CONNECTs that reached the broker
  int drops = 0;
  std::string clientId;
  Msg will;
  std::map<std::string, uint8_t> subscriptions;
  std::map<std::string, std::string> retained;
  std::vector<std::pair<std::string, std::string>> inbox;
  std::vector<Msg> published;
};

// A device wired to the fakes, with helpers to run its loop.
struct Rig {
  explicit Rig(gf::DeviceConfig cfg = defaultConfig())
      : config(std::move(cfg)), device(config, mqtt, link, clock, &log) {
    mqtt.device = &device;
    mqtt.clock = &clock;
  }
  static gf::DeviceConfig defaultConfig() {
    gf::DeviceConfig c;
    c.root = "t/fw";
    c.unit = "unit1";
    c.device = "dev1";
    return c;
  }
  // Run the loop for `ms` milliseconds in 1 ms passes with the button as given.
  void run(uint32_t ms, bool pressed = false) {
    for (uint32_t i = 0; i < ms; ++i) {
      device.tick(false, pressed);
      clock.advance(1);
    }
  }
  void tick(bool edge = false, bool pressed = false) { device.tick(edge, pressed); }

  gf::DeviceConfig config;
  FakeClock clock;
  FakeLink link;
  FakeMqtt mqtt;
  FakeLog log;
  gf::Device device;
};

}  // namespace gft
