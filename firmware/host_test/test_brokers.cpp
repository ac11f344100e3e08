// A list of brokers (a cluster's nodes): GF_MQTT_BROKERS parsed and refused item by item, and the
// device moving to the next broker when its own is lost, backing off only after a whole round.
#include <doctest/doctest.h>

#include <string>
#include <vector>

#include "../esp32_unit/src/brokers.h"
#include "fakes.h"

using gft::Rig;

namespace {
const std::string kDir = "t/fw/v1/units/unit1/direction";
const std::string kEstop = "t/fw/v1/fleet/estop";
const std::string kA = "10.0.0.1:1883";
const std::string kB = "10.0.0.2:1883";
const std::string kC = "broker-c.lan:1884";

std::vector<gf::Broker> parsed(const std::string& text, bool tls = false) {
  std::vector<gf::Broker> out;
  const std::string problem = gf::parseBrokers(text, tls, out);
  INFO(problem);
  CHECK(problem.empty());
  return out;
}

std::string refused(const std::string& text, bool tls = false) {
  std::vector<gf::Broker> out(1, gf::Broker("left", 1));
  const std::string problem = gf::parseBrokers(text, tls, out);
  CHECK(out.empty());
  return problem;
}

bool has(const std::string& text, const std::string& part) {
  INFO(text);
  return text.find(part) != std::string::npos;
}

gf::DeviceConfig threeBrokers() {
  gf::DeviceConfig cfg = Rig::defaultConfig();
  cfg.brokers = parsed(kA + "," + kB + "," + kC);
  cfg.mqttBackoffInitialMs = 100;
  cfg.mqttBackoffMaxMs = 1600;
  return cfg;
}

// Run the loop for `ms` 1 ms passes, noting each connection attempt's time.
std::vector<uint32_t> attemptTimes(Rig& r, uint32_t ms) {
  std::vector<uint32_t> at;
  for (uint32_t i = 0; i < ms; ++i) {
    const int before = r.mqtt.connectCalls;
    r.tick();
    if (r.mqtt.connectCalls != before) at.push_back(r.clock.now);
    r.clock.advance(1);
  }
  return at;
}
}  // namespace

TEST_CASE("GF_MQTT_BROKERS: host:port items, comma-separated, default ports by TLS") {
  const auto one = parsed("192.168.1.10:8883", true);
  REQUIRE(one.size() == 1);
  CHECK(one[0].host == "192.168.1.10");
  CHECK(one[0].port == 8883);
  const auto list = parsed(" 10.0.0.1:1883, mqtt://10.0.0.2 ,broker-c.lan:1884");
  REQUIRE(list.size() == 3);
  CHECK(list[1].name() == "10.0.0.2:1883");  // plain TCP's default port
  CHECK(gf::brokerNames(list) == "10.0.0.1:1883, 10.0.0.2:1883, broker-c.lan:1884");
  const auto tls = parsed("mqtts://a.lan,b.lan", true);
  REQUIRE(tls.size() == 2);
  CHECK(tls[0].name() == "a.lan:8883");
  CHECK(tls[1].name() == "b.lan:8883");
}

TEST_CASE("a bad item of GF_MQTT_BROKERS is refused in one line naming it") {
  CHECK(has(refused(""), "no broker"));
  CHECK(has(refused("a:1883,,b:1883"), "an empty item"));
  CHECK(has(refused("a:1883,"), "an empty item"));
  CHECK(has(refused("a:1883,A:1883"), "A:1883 is in it twice"));  // host names: any case
  CHECK(has(refused("a:1883,b:1883,a"), "a:1883 is in it twice"));  // the default port
  CHECK(has(refused("a:1883,ws://b:9001"), "item 'ws://b:9001': the device speaks MQTT over TCP"));
  CHECK(has(refused("wss://b:9001", true), "not over websockets"));
  CHECK(has(refused("a:1883,mqtts://b:8883"), "item 'mqtts://b:8883': TLS (mqtts://) needs"));
  CHECK(has(refused("a:8883,mqtt://b:1883", true), "item 'mqtt://b:1883': plain TCP"));
  CHECK(has(refused("http://a:80"), "unknown scheme 'http://'"));
  CHECK(has(refused("a:1883,b:99999"), "item 'b:99999': port 99999 is not 1-65535"));
  CHECK(has(refused("a:0"), "port 0 is not 1-65535"));
  CHECK(has(refused("a:"), "item 'a:': port '' is not a number"));
  CHECK(has(refused("a:18x3"), "port '18x3' is not a number"));
  CHECK(has(refused(":1883"), "item ':1883': no host"));
  CHECK(has(refused("user:pw@a:1883"), "no login here: the account goes in GF_MQTT_USER"));
  CHECK(has(refused("mqtt://a:1883/path"), "host:port only, no path"));
  CHECK(has(refused("[fd00::1]:1883"), "is not a host name or IPv4 address"));
  for (const char* text : {"a:1883,,b", "a:1883,b:0", "ws://x:1"}) {
    CHECK(refused(text).find('\n') == std::string::npos);
  }
  // The device refuses to start with it (config.h problem), as with any other bad setting.
  gf::DeviceConfig cfg = Rig::defaultConfig();
  cfg.brokers.clear();
  CHECK(has(cfg.problem(), "no broker"));
}

TEST_CASE("the rotation: the next broker at once until a whole round has failed") {
  gf::BrokerRotation rotation(3);
  CHECK(rotation.current() == 0);
  CHECK(rotation.failed());  // 0 failed: 1 at once
  CHECK(rotation.current() == 1);
  CHECK(rotation.failed());  // 1 failed: 2 at once
  CHECK_FALSE(rotation.failed());  // 2 failed too: the round is over, back off
  CHECK(rotation.current() == 0);
  CHECK(rotation.failed());  // a new round
  rotation.connected();  // on broker 1
  rotation.lost();  // it died: on to 2, a new round
  CHECK(rotation.current() == 2);
  CHECK(rotation.failed());
  CHECK(rotation.failed());
  CHECK_FALSE(rotation.failed());
  gf::BrokerRotation single(1);  // one broker: every failure backs off, as it always did
  CHECK_FALSE(single.failed());
  CHECK_FALSE(single.failed());
  CHECK(single.current() == 0);
}

TEST_CASE("a device on a list moves to the next broker when its own dies, and reads afresh") {
  Rig r(threeBrokers());
  r.mqtt.retained[kDir] = "E";
  r.run(2);
  REQUIRE(r.device.online());
  CHECK(r.mqtt.on == kA);
  CHECK(r.log.has("MQTT: connected as dev1 to broker " + kA + ", showing " + kDir));
  CHECK(r.device.direction() == gf::Direction::E);

  r.mqtt.retained[kDir] = "S";  // meanwhile, on the cluster
  r.mqtt.kill(kA);
  r.run(3);
  REQUIRE(r.device.online());
  CHECK(r.mqtt.on == kB);  // the next one, at once: no back-off
  CHECK(r.mqtt.attempts == std::vector<std::string>{kA, kB});
  CHECK(r.log.has("MQTT: connection lost (broker " + kA + "); trying broker " + kB));
  CHECK(r.log.has("MQTT: connected as dev1 to broker " + kB));
  // A new session there: subscribed again, the retained values read again.
  CHECK(r.mqtt.subscriptions.count(kDir) == 1);
  CHECK(r.mqtt.subscriptions.count(kEstop) == 1);
  CHECK(r.device.direction() == gf::Direction::S);
  CHECK(r.mqtt.connectPackets == 2);
}

TEST_CASE("with every broker down it tries each in turn at once, then backs off between rounds") {
  Rig r(threeBrokers());
  r.run(2);
  REQUIRE(r.mqtt.on == kA);
  r.mqtt.down = {kA, kB, kC};
  r.mqtt.kill(kA);
  const auto at = attemptTimes(r, 3200);
  // B (the next after the lost one), C, A at once; then the back-off doubles between rounds.
  REQUIRE(at.size() >= 12);
  const std::vector<std::string> round = {kB, kC, kA};
  for (size_t i = 0; i < 12; ++i) CHECK(r.mqtt.attempts[i + 1] == round[i % 3]);
  std::vector<uint32_t> gaps;
  for (size_t i = 1; i < 12; ++i) gaps.push_back(at[i] - at[i - 1]);
  CHECK(gaps == std::vector<uint32_t>{1, 1, 100, 1, 1, 200, 1, 1, 400, 1, 1});
  CHECK(r.log.has("MQTT: connect failed at broker " + kB + ": broker down; trying broker " + kC +
                  " at once"));
  CHECK(r.log.has("MQTT: connect failed at broker " + kA +
                  ": broker down; every broker failed; next try in 100 ms, at broker " + kB));
  CHECK_FALSE(r.device.online());

  // One node back: the device reaches it within the round, and the back-off starts over.
  r.mqtt.down.erase(kC);
  r.run(1700);
  REQUIRE(r.device.online());
  CHECK(r.mqtt.on == kC);
  r.mqtt.kill(kC);
  r.mqtt.down.erase(kA);
  const auto again = attemptTimes(r, 150);
  CHECK(again.size() == 1);  // A, next after C, at once
  CHECK(r.mqtt.on == kA);
  CHECK(r.device.online());
}

TEST_CASE("a slow dead broker costs its attempt, and the next broker follows it at once") {
  Rig r(threeBrokers());
  r.mqtt.down = {kA};
  r.mqtt.connectTakesMs = 5000;  // a dead TLS node: the attempt waits for the handshake
  r.run(2);
  CHECK(r.mqtt.attempts == std::vector<std::string>{kA, kB});
  CHECK(r.device.online());
  CHECK(r.mqtt.on == kB);
}

TEST_CASE("a WiFi drop keeps the device on its broker: the broker was not to blame") {
  Rig r(threeBrokers());
  r.run(2);
  REQUIRE(r.mqtt.on == kA);
  r.link.isUp = false;
  r.mqtt.drop();
  r.run(10);
  r.link.isUp = true;
  r.run(3);
  REQUIRE(r.device.online());
  CHECK(r.mqtt.attempts == std::vector<std::string>{kA, kA});
}

TEST_CASE("a broker refusing a subscription is left for the next, like a failed attempt") {
  Rig r(threeBrokers());
  r.mqtt.refuseTopics = {kEstop};
  r.run(1);  // connected to A, which refuses: left in the same pass
  CHECK(r.log.has("the broker refused a subscription"));
  CHECK(r.log.has("(broker " + kA + "); trying broker " + kB + " at once"));
  r.mqtt.refuseTopics.clear();
  r.run(5);
  REQUIRE(r.device.online());
  CHECK(r.mqtt.on == kB);
}
