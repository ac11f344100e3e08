#include <doctest/doctest.h>

#include <map>
#include <string>
#include <utility>

#include "fakes.h"

using gf::Direction;
using gft::Rig;

namespace {
const std::string kDir = "t/fw/v1/units/unit1/direction";
const std::string kEstop = "t/fw/v1/fleet/estop";
const std::string kConn = "t/fw/v1/devices/dev1/connection";
const std::string kPress = "t/fw/v1/devices/dev1/stop";
const std::string kStop = "engaged|dev1|button";

// One physical press: the interrupt fires on each bounce, the loop runs every millisecond.
void bouncyPress(Rig& r) {
  for (int i = 0; i < 10; ++i) {
    r.tick(true, i % 2 == 0);
    r.clock.advance(1);
  }
  r.run(150, true);  // held
  for (int i = 0; i < 6; ++i) {
    r.tick(true, i % 2 == 1);
    r.clock.advance(1);
  }
  r.run(200, false);
}
}  // namespace

TEST_CASE("connects with its last will, says online, subscribes to direction, estop, its press") {
  Rig r;
  r.tick();
  CHECK(r.device.online());
  CHECK(r.mqtt.clientId == "dev1");
  CHECK(r.mqtt.will.topic == kConn);
  CHECK(r.mqtt.will.payload == "broken");
  CHECK(r.mqtt.count(kConn, "online") == 1);
  CHECK(r.mqtt.subscriptions.at(kDir) == 0);  // every subscription at QoS 0 (protocol.md 2)
  CHECK(r.mqtt.subscriptions.at(kEstop) == 0);
  CHECK(r.mqtt.subscriptions.at(kPress) == 0);
  CHECK(r.mqtt.retained.at(kConn) == "online");
}

TEST_CASE("LEDs follow the unit's direction messages") {
  Rig r;
  r.tick();
  for (auto [payload, want] : {std::pair{"N", gf::Leds{true, false, false, false}},
                               std::pair{"E", gf::Leds{false, true, false, false}},
                               std::pair{"S", gf::Leds{false, false, true, false}},
                               std::pair{"W", gf::Leds{false, false, false, true}},
                               std::pair{"-", gf::Leds{}}}) {
    r.mqtt.route(kDir, payload, true);
    r.tick();
    CHECK(r.device.leds() == want);
  }
}

TEST_CASE("retained direction and estop are read on connect") {
  Rig r;
  r.mqtt.route(kDir, "S", true);
  r.mqtt.route(kEstop, "released|dashboard|ok", true);
  r.tick();  // connect, subscribe
  r.tick();  // retained values delivered
  CHECK(r.device.direction() == Direction::S);
  CHECK_FALSE(r.device.estopEngaged());
  CHECK(r.device.leds() == gf::Leds{false, false, true, false});
}

TEST_CASE("the stop pattern wins over the direction until released") {
  Rig r;
  r.tick();
  r.mqtt.route(kDir, "E", true);
  r.mqtt.route(kEstop, "engaged|dashboard|operator pressed STOP", true);
  r.tick();
  CHECK(r.device.estopEngaged());
  r.clock.now = 0;
  CHECK(r.device.leds().count() == 4);
  r.clock.now = gf::kBlinkHalfPeriodMs;
  CHECK(r.device.leds().count() == 0);
  r.mqtt.route(kEstop, "released|dashboard|checked", true);
  r.tick();
  CHECK(r.device.leds() == gf::Leds{false, true, false, false});
}

TEST_CASE("malformed or oversized payloads change nothing") {
  Rig r;
  r.tick();
  r.mqtt.route(kDir, "W", true);
  r.mqtt.route(kEstop, "engaged|dashboard|stop", true);
  r.tick();
  const std::string oversized = "released|dashboard|" + std::string(600, 'x');
  for (const std::string& bad : {std::string(""), std::string("north"), std::string("X"),
                                 std::string("N\n"), std::string(100, 'N')}) {
    r.mqtt.route(kDir, bad, true);
  }
  for (const std::string& bad : {std::string(""), std::string("released"), std::string("stop"),
                                 std::string("released||x"), std::string("released|a|b\nc"),
                                 oversized}) {
    r.mqtt.route(kEstop, bad, true);
  }
  r.tick();
  CHECK(r.device.direction() == Direction::W);
  CHECK(r.device.estopEngaged());
  // Messages on topics it did not ask for are ignored too.
  r.device.onMessage("t/fw/v1/units/unit2/direction", reinterpret_cast<const uint8_t*>("N"), 1);
  CHECK(r.device.direction() == Direction::W);
}

TEST_CASE("a bouncy button press yields exactly one stop message") {
  Rig r;
  r.tick();
  bouncyPress(r);
  r.run(5000);  // far past the retry period: confirmed, so never sent again
  CHECK(r.mqtt.count(kPress, kStop) == 1);
  CHECK(r.mqtt.count(kEstop, kStop) == 0);  // a device never writes the fleet's latch
  CHECK(r.mqtt.published.back().retained);
  CHECK(r.mqtt.retained.at(kPress) == kStop);
  CHECK(r.device.pressed());
  CHECK(r.device.leds().count() % 4 == 0);  // held: the stop pattern, latch or not
  CHECK_FALSE(r.device.stopPending());
}

TEST_CASE("a held press shows the stop until the release clears it") {
  Rig r;
  r.tick();
  r.mqtt.route(kDir, "E", true);
  bouncyPress(r);
  r.mqtt.route(kEstop, "released|dashboard|checked", true);  // released, not yet cleared
  r.run(10);
  CHECK(r.device.pressed());
  r.mqtt.route(kPress, "", true);  // the coordinator clears the press after the release
  r.run(10);
  CHECK_FALSE(r.device.pressed());
  CHECK(r.device.leds() == gf::Leds{false, true, false, false});
}

TEST_CASE("two separate presses send two stops") {
  Rig r;
  r.tick();
  bouncyPress(r);
  r.mqtt.route(kEstop, "released|dashboard|checked", true);
  r.mqtt.route(kPress, "", true);
  r.run(10);
  bouncyPress(r);
  CHECK(r.mqtt.count(kPress, kStop) == 2);
}

TEST_CASE("a press while disconnected is sent after reconnect, once") {
  Rig r;
  r.tick();
  r.mqtt.drop();
  r.mqtt.brokerUp = false;
  CHECK(r.mqtt.retained.at(kConn) == "broken");  // the will
  r.run(10);
  CHECK_FALSE(r.device.online());
  bouncyPress(r);
  CHECK(r.device.stopPending());
  CHECK(r.device.leds().count() % 4 == 0);  // the stop pattern shows the press at once
  r.run(3000);
  CHECK(r.mqtt.count(kPress, kStop) == 0);
  r.mqtt.brokerUp = true;
  r.run(40000);  // within the longest back-off
  CHECK(r.device.online());
  CHECK(r.mqtt.count(kPress, kStop) == 1);
  CHECK(r.mqtt.retained.at(kPress) == kStop);
  CHECK(r.mqtt.retained.at(kConn) == "online");
  CHECK_FALSE(r.device.stopPending());
}

TEST_CASE("a press whose publish is lost is retried until it comes back") {
  Rig r;
  r.tick();
  r.mqtt.dropPublishes = true;
  bouncyPress(r);
  CHECK(r.mqtt.count(kPress, kStop) == 1);
  r.run(r.config.stopRetryMs);
  CHECK(r.mqtt.count(kPress, kStop) == 2);
  r.mqtt.dropPublishes = false;
  r.run(r.config.stopRetryMs);
  CHECK(r.mqtt.count(kPress, kStop) == 3);
  r.run(10 * r.config.stopRetryMs);
  CHECK(r.mqtt.count(kPress, kStop) == 3);
  CHECK_FALSE(r.device.stopPending());
}

TEST_CASE("a press is not confirmed by someone else's engaged") {
  Rig r;
  r.tick();
  r.mqtt.dropPublishes = true;
  bouncyPress(r);
  r.mqtt.route(kEstop, "engaged|dashboard|x", true);
  r.mqtt.route(kEstop, kStop, true);  // the coordinator's copy in the latch is not our press
  r.mqtt.route(kPress, "released|dev1|button", true);
  r.run(10);
  CHECK(r.device.stopPending());
}

TEST_CASE("reconnect attempts back off, grow, cap, and do not block the loop") {
  gf::DeviceConfig cfg = Rig::defaultConfig();
  cfg.mqttBackoffInitialMs = 100;
  cfg.mqttBackoffMaxMs = 1600;
  Rig r(cfg);
  r.mqtt.brokerUp = false;
  std::vector<uint32_t> attemptsAt;
  for (uint32_t t = 0; t < 10000; ++t) {
    int before = r.mqtt.connectCalls;
    r.tick();
    if (r.mqtt.connectCalls != before) attemptsAt.push_back(r.clock.now);
    r.clock.advance(1);
  }
  REQUIRE(attemptsAt.size() >= 8);
  std::vector<uint32_t> gaps;
  for (size_t i = 1; i < attemptsAt.size(); ++i) gaps.push_back(attemptsAt[i] - attemptsAt[i - 1]);
  CHECK(gaps[0] == 100);
  CHECK(gaps[1] == 200);
  CHECK(gaps[2] == 400);
  CHECK(gaps[3] == 800);
  CHECK(gaps[4] == 1600);
  CHECK(gaps[5] == 1600);
  CHECK(gaps.back() == 1600);
  // Once the broker is back the next attempt succeeds and the back-off starts over.
  r.mqtt.brokerUp = true;
  r.run(1600);
  CHECK(r.device.online());
  r.mqtt.drop();
  r.mqtt.brokerUp = false;
  int before = r.mqtt.connectCalls;
  r.run(150);
  CHECK(r.mqtt.connectCalls - before == 2);  // at once, then after 100 ms
}

TEST_CASE("a session whose subscriptions fail is dropped and retried with back-off") {
  Rig r;
  r.mqtt.failSubscribe = true;
  r.tick();
  CHECK_FALSE(r.device.online());
  CHECK_FALSE(r.mqtt.connected());
  // Dropped without a DISCONNECT: the broker keeps the will, which replaces the `online`.
  CHECK(r.mqtt.retained.at(kConn) == "broken");
  r.run(r.config.mqttBackoffInitialMs - 1);
  CHECK(r.mqtt.connectCalls == 1);
  r.mqtt.failSubscribe = false;
  r.run(2);
  CHECK(r.mqtt.connectCalls == 2);
  CHECK(r.device.online());
}

TEST_CASE("without WiFi it does not try MQTT, restarts joining with back-off, shows offline") {
  Rig r;
  r.link.isUp = false;
  r.run(10);
  CHECK(r.link.begins == 1);
  CHECK(r.mqtt.connectCalls == 0);
  CHECK(r.device.leds().count() == 1);  // the offline chase
  r.run(r.config.linkBackoffInitialMs);
  CHECK(r.link.begins == 2);
  r.link.isUp = true;
  r.run(2);
  CHECK(r.device.online());
  r.mqtt.route(kDir, "N", true);
  r.run(2);
  CHECK(r.device.leds() == gf::Leds{true, false, false, false});
  // WiFi goes: offline pattern at once, MQTT reconnects after it returns.
  r.link.isUp = false;
  r.mqtt.drop();
  r.run(2);
  CHECK_FALSE(r.device.online());
  r.link.isUp = true;
  r.run(2);
  CHECK(r.device.online());
}

TEST_CASE("invalid configuration is reported") {
  gf::DeviceConfig c = Rig::defaultConfig();
  CHECK(c.problem().empty());
  c.unit = "unit 1";
  CHECK(c.problem().find("unit id") != std::string::npos);
  c = Rig::defaultConfig();
  c.root = "a/+";
  CHECK(c.problem().find("root") != std::string::npos);
  c = Rig::defaultConfig();
  c.device = "";
  CHECK(c.problem().find("device id") != std::string::npos);
}

TEST_CASE("what the device subscribes to and publishes is what protocol_table.h says") {
  namespace p = gf::proto;
  Rig r;  // root t/fw, unit unit1, device dev1
  r.tick();
  REQUIRE(r.device.online());
  const std::string prefix = std::string("t/fw/") + p::kTopicVersion + "/";
  const std::string dir = prefix + p::kTopicDirectionBefore + "unit1" + p::kTopicDirectionAfter;
  const std::string estop = prefix + p::kTopicEstop;
  const std::string press = prefix + p::kTopicDeviceStopBefore + "dev1" + p::kTopicDeviceStopAfter;
  const std::string conn =
      prefix + p::kTopicDeviceConnectionBefore + "dev1" + p::kTopicDeviceConnectionAfter;
  // Exactly its unit's direction, the fleet's stop and its own press, each at kSubscribeQos (0).
  static_assert(p::kSubscribeQos == 0, "protocol.md 2: every subscription at QoS 0");
  CHECK(r.mqtt.subscriptions == std::map<std::string, uint8_t>{{dir, p::kSubscribeQos},
                                                               {estop, p::kSubscribeQos},
                                                               {press, p::kSubscribeQos}});
  CHECK(r.mqtt.will.topic == conn);
  CHECK(r.mqtt.will.payload == p::kDeviceWill);
  REQUIRE(r.mqtt.published.size() == 1);
  CHECK(r.mqtt.published[0].topic == conn);
  CHECK(r.mqtt.published[0].payload == p::kDeviceOnline);
  CHECK(r.mqtt.published[0].retained == p::kTopicDeviceConnectionRetained);

  const std::pair<char, gf::Leds> letters[] = {{p::kDirectionN, gf::Leds{true, false, false, false}},
                                               {p::kDirectionE, gf::Leds{false, true, false, false}},
                                               {p::kDirectionS, gf::Leds{false, false, true, false}},
                                               {p::kDirectionW, gf::Leds{false, false, false, true}},
                                               {p::kDirectionNone, gf::Leds{}}};
  for (const auto& letter : letters) {
    r.mqtt.route(dir, std::string(1, letter.first), p::kTopicDirectionRetained);
    r.tick();
    CHECK(r.device.leds() == letter.second);
  }

  const std::string sep(1, p::kEstopSeparator);
  r.mqtt.route(estop, p::kEstopEngaged + sep + "dashboard" + sep + "x", p::kTopicEstopRetained);
  r.tick();
  CHECK(r.device.estopEngaged());
  r.mqtt.route(estop, p::kEstopReleased + sep + "dashboard", p::kTopicEstopRetained);
  r.tick();
  CHECK_FALSE(r.device.estopEngaged());

  bouncyPress(r);
  REQUIRE(r.mqtt.published.size() == 2);
  CHECK(r.mqtt.published[1].topic == press);
  CHECK(r.mqtt.published[1].payload == p::kEstopEngaged + sep + "dev1" + sep + gf::kButtonReason);
  CHECK(r.mqtt.published[1].retained == p::kTopicDeviceStopRetained);
}

TEST_CASE("a press cleared while offline is not shown after reconnecting") {
  Rig r;
  r.tick();
  r.mqtt.route(kDir, "E", true);
  bouncyPress(r);
  CHECK(r.device.pressed());
  r.mqtt.drop();
  r.mqtt.brokerUp = false;
  r.run(10);
  CHECK_FALSE(r.device.online());
  r.mqtt.retained.erase(kPress);  // meanwhile an operator released and the press was cleared
  r.mqtt.retained[kEstop] = "released|operator|checked";
  r.mqtt.brokerUp = true;
  r.run(40000);  // reconnected: the retained values come back, no press among them
  REQUIRE(r.device.online());
  CHECK_FALSE(r.device.pressed());
  CHECK(r.device.leds() == gf::Leds{false, true, false, false});
}

TEST_CASE("a subscription the broker refuses drops the session, says so, retries with back-off") {
  Rig r;
  r.mqtt.refuseTopics.insert(kEstop);  // PubSubClient's subscribe() still says true
  r.tick();
  r.tick();  // the refusing SUBACK arrives
  CHECK_FALSE(r.device.online());
  CHECK_FALSE(r.mqtt.connected());
  CHECK(r.mqtt.retained.at(kConn) == "broken");  // no DISCONNECT: the will stands
  CHECK(r.log.has("refused a subscription"));
  CHECK(r.log.has(kEstop));
  const int before = r.mqtt.connectPackets;
  r.run(r.config.mqttBackoffInitialMs - 2);
  CHECK(r.mqtt.connectPackets == before);  // back-off, not a tight reconnect loop
  r.mqtt.refuseTopics.clear();
  r.run(5);
  CHECK(r.mqtt.connectPackets == before + 1);
  r.run(2);
  CHECK(r.device.online());
}

TEST_CASE("after WiFi drops, the next connect is a new session even if the old socket looks open") {
  Rig r;
  r.tick();
  REQUIRE(r.mqtt.connectPackets == 1);
  r.link.isUp = false;  // the socket of the old session is not closed by the WiFi drop itself
  r.run(5);
  CHECK_FALSE(r.device.online());
  r.link.isUp = true;
  r.run(5);
  REQUIRE(r.device.online());
  // PubSubClient's connect() would have said yes to the stale session without a CONNECT.
  CHECK(r.mqtt.connectPackets == 2);
  CHECK(r.mqtt.subscriptions.size() == 3);
  CHECK(r.mqtt.retained.at(kConn) == "online");
}

TEST_CASE("the log says why a connect failed, when it tries again, and what WiFi does") {
  Rig r;
  r.link.isUp = false;
  r.run(r.config.linkBackoffInitialMs + 1);
  CHECK(r.log.has("WiFi: not joined yet (wrong password); joining again"));
  r.mqtt.brokerUp = false;
  r.mqtt.error = "the broker refused the user name or password";
  r.link.isUp = true;
  r.tick();
  CHECK(r.log.has("WiFi: connected"));
  CHECK(r.log.has("MQTT: connect failed: the broker refused the user name or password; next try "
                  "in 500 ms"));
  r.mqtt.brokerUp = true;
  r.run(600);
  CHECK(r.log.has("MQTT: connected as dev1"));
  r.mqtt.drop();
  r.run(2);
  CHECK(r.log.has("MQTT: connection lost"));
}

TEST_CASE("the back-off runs from the end of a failed attempt, however long it blocked") {
  Rig r;
  r.mqtt.brokerUp = false;
  r.mqtt.connectTakesMs = 5000;  // a dead TLS broker: each attempt waits for the handshake
  std::vector<std::pair<uint32_t, uint32_t>> attempts;  // start, end
  for (int i = 0; i < 20000 && attempts.size() < 3; ++i) {
    const uint32_t start = r.clock.now;
    const int before = r.mqtt.connectCalls;
    r.tick();
    if (r.mqtt.connectCalls != before) attempts.emplace_back(start, r.clock.now);
    r.clock.advance(1);
  }
  REQUIRE(attempts.size() == 3);
  CHECK(attempts[1].first - attempts[0].second == r.config.mqttBackoffInitialMs);
  CHECK(attempts[2].first - attempts[1].second == 2 * r.config.mqttBackoffInitialMs);
}
