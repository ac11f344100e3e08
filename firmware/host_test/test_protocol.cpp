#include <doctest/doctest.h>

#include <cctype>
#include <string>
#include <utility>

#include "../esp32_unit/src/device.h"
#include "../esp32_unit/src/protocol.h"

using gf::Direction;
using gf::EstopKind;

namespace {
EstopKind estop(const std::string& s) {
  return gf::parseEstop(reinterpret_cast<const uint8_t*>(s.data()), s.size());
}
bool direction(const std::string& s, Direction& out) {
  return gf::parseDirection(reinterpret_cast<const uint8_t*>(s.data()), s.size(), out);
}
}  // namespace

TEST_CASE("topics are the ones protocol.md names") {
  CHECK(gf::directionTopic("gridfleet", "unit1") == "gridfleet/v1/units/unit1/direction");
  CHECK(gf::estopTopic("lab/a") == "lab/a/v1/fleet/estop");
  CHECK(gf::deviceStopTopic("lab/a", "dev1") == "lab/a/v1/devices/dev1/stop");
  CHECK(gf::deviceConnectionTopic("gridfleet", "esp-1") == "gridfleet/v1/devices/esp-1/connection");
}

TEST_CASE("ids and roots are checked like the Python side") {
  CHECK(gf::isValidId("unit1"));
  CHECK(gf::isValidId("a.b_c-d"));
  CHECK(gf::isValidId(std::string(64, 'x')));
  CHECK_FALSE(gf::isValidId(std::string(65, 'x')));
  CHECK_FALSE(gf::isValidId(""));
  CHECK_FALSE(gf::isValidId("-x"));
  CHECK_FALSE(gf::isValidId("a/b"));
  CHECK_FALSE(gf::isValidId("a+"));
  CHECK(gf::isValidRoot("gridfleet"));
  CHECK(gf::isValidRoot("t/fw-1"));
  CHECK_FALSE(gf::isValidRoot(""));
  CHECK_FALSE(gf::isValidRoot("a//b"));
  CHECK_FALSE(gf::isValidRoot("a/#"));
  CHECK_FALSE(gf::isValidRoot("a/"));
}

TEST_CASE("direction payloads: exactly one of N E S W -") {
  Direction d = Direction::E;
  CHECK(direction("N", d));
  CHECK(d == Direction::N);
  CHECK(direction("-", d));
  CHECK(d == Direction::None);
  CHECK(direction("W", d));
  CHECK(d == Direction::W);
  for (const char* bad : {"", "n", "X", "NE", "N\n", " N", "--"}) {
    Direction before = d;
    CHECK_FALSE(direction(bad, d));
    CHECK(d == before);
  }
  CHECK_FALSE(gf::parseDirection(nullptr, 1, d));
}

TEST_CASE("estop payloads") {
  CHECK(estop("engaged|dashboard|operator pressed STOP") == EstopKind::Engaged);
  CHECK(estop("released|dashboard|area checked") == EstopKind::Released);
  CHECK(estop("engaged|dev1|") == EstopKind::Engaged);
  CHECK(estop("engaged|dev1") == EstopKind::Engaged);
  CHECK(estop("engaged|dev1|r\xc3\xa9sum\xc3\xa9") == EstopKind::Engaged);  // UTF-8 reason
  CHECK(estop(gf::buttonEstopPayload("dev1")) == EstopKind::Engaged);
  CHECK(gf::buttonEstopPayload("dev1") == "engaged|dev1|button");
  for (const std::string& bad :
       {std::string(""), std::string("engaged"), std::string("ENGAGED|x|y"), std::string("engaged||y"),
        std::string("engaged|a/b|y"), std::string("engagedx|a|b"), std::string("released"),
        std::string("engaged|a|line\nbreak"), std::string("engaged|a|\xff\xfe"),
        std::string("engaged|a|\xc3"), std::string("engaged|a|x\0y", 13), std::string("stop"),
        std::string("engaged|a|") + std::string(201, 'r')}) {
    CHECK_MESSAGE(estop(bad) == EstopKind::Invalid, bad);
  }
  CHECK(estop("engaged|a|" + std::string(200, 'r')) == EstopKind::Engaged);
  // 200 two-byte characters are 400 bytes: still within both limits.
  std::string accents;
  for (int i = 0; i < 200; ++i) accents += "\xc3\xa9";
  CHECK(estop("engaged|a|" + accents) == EstopKind::Engaged);
  // Oversized: more than 512 bytes is refused whatever it says.
  std::string big = "engaged|a|";
  for (int i = 0; i < 200; ++i) big += "\xe2\x82\xac";  // 600 bytes of euro signs
  CHECK(big.size() > gf::kMaxEstopBytes);
  CHECK(estop(big) == EstopKind::Invalid);
  CHECK(gf::parseEstop(nullptr, 0) == EstopKind::Invalid);
}

// The generated protocol_table.h (make schemas) is the reference from here on: the firmware must
// say what it says, whatever the code above spells out by hand.
namespace {
std::string fill(const std::string& pattern, const std::string& placeholder, const std::string& value) {
  std::string out = pattern;
  const size_t at = out.find(placeholder);
  REQUIRE(at != std::string::npos);
  return out.replace(at, placeholder.size(), value);
}
}  // namespace

TEST_CASE("topic names are built as protocol_table.h's patterns say") {
  namespace p = gf::proto;
  const std::string prefix = std::string("lab/a/") + p::kTopicVersion + "/";
  CHECK(gf::directionTopic("lab/a", "u-1") == prefix + fill(p::kTopicDirectionPattern, "{unit}", "u-1"));
  CHECK(gf::estopTopic("lab/a") == prefix + p::kTopicEstop);
  CHECK(gf::deviceConnectionTopic("lab/a", "esp.2") ==
        prefix + fill(p::kTopicDeviceConnectionPattern, "{device}", "esp.2"));
}

TEST_CASE("ids follow protocol_table.h: length and punctuation") {
  namespace p = gf::proto;
  CHECK(gf::isValidId(std::string(p::kMaxIdChars, 'a')));
  CHECK_FALSE(gf::isValidId(std::string(p::kMaxIdChars + 1, 'a')));
  CHECK(gf::isValidRoot(std::string(p::kMaxIdChars, 'a') + "/b"));
  CHECK_FALSE(gf::isValidRoot(std::string(p::kMaxIdChars + 1, 'a')));
  const std::string punctuation = p::kIdPunctuation;
  for (int c = 1; c < 128; ++c) {
    const char ch = static_cast<char>(c);
    const bool alnum = std::isalnum(c) != 0;
    const bool allowed = alnum || punctuation.find(ch) != std::string::npos;
    CHECK_MESSAGE(gf::isValidId(std::string("a") + ch) == allowed, c);
    CHECK_MESSAGE(gf::isValidId(std::string(1, ch) + "a") == alnum, c);
  }
}

TEST_CASE("direction payloads: exactly protocol_table.h's letters") {
  namespace p = gf::proto;
  const std::pair<char, Direction> letters[] = {{p::kDirectionN, Direction::N},
                                                {p::kDirectionE, Direction::E},
                                                {p::kDirectionS, Direction::S},
                                                {p::kDirectionW, Direction::W},
                                                {p::kDirectionNone, Direction::None}};
  int accepted = 0;
  for (int b = 0; b < 256; ++b) {
    const uint8_t byte = static_cast<uint8_t>(b);
    Direction d = Direction::E;
    const bool ok = gf::parseDirection(&byte, 1, d);
    accepted += ok;
    for (const auto& letter : letters) {
      if (static_cast<uint8_t>(letter.first) == byte) CHECK((ok && d == letter.second));
    }
  }
  CHECK(accepted == 5);
  CHECK(p::kTopicDirectionMaxBytes >= 1);
}

TEST_CASE("estop payloads: protocol_table.h's words, separator and limits") {
  namespace p = gf::proto;
  const std::string sep(1, p::kEstopSeparator);
  CHECK(estop(std::string(p::kEstopEngaged) + sep + "dev1" + sep + "x") == EstopKind::Engaged);
  CHECK(estop(std::string(p::kEstopReleased) + sep + "dev1") == EstopKind::Released);
  CHECK(gf::buttonEstopPayload("dev1") ==
        std::string(p::kEstopEngaged) + sep + "dev1" + sep + gf::kButtonReason);
  const std::string head = std::string(p::kEstopEngaged) + sep + "a" + sep;
  CHECK(estop(head + std::string(p::kMaxEstopReasonChars, 'r')) == EstopKind::Engaged);
  CHECK(estop(head + std::string(p::kMaxEstopReasonChars + 1, 'r')) == EstopKind::Invalid);
  // Exactly kMaxEstopBytes bytes in few enough characters is fine; one byte more is not.
  std::string big = head;
  while (big.size() + 4 <= p::kMaxEstopBytes) big += "\xf0\x9f\x9b\x91";  // 4-byte characters
  while (big.size() < p::kMaxEstopBytes) big += "r";
  REQUIRE(big.size() == p::kMaxEstopBytes);
  CHECK(estop(big) == EstopKind::Engaged);
  CHECK(estop(big + "r") == EstopKind::Invalid);
  CHECK(p::kTopicEstopMaxBytes == p::kMaxEstopBytes);
}

TEST_CASE("a topic root is refused when the longest estop would not fit the MQTT buffer") {
  namespace p = gf::proto;
  // The 512-byte estop arrives as a QoS 1 PUBLISH: 1 + 2 header bytes, 2 topic length bytes,
  // the topic, 2 packet id bytes, the payload; PubSubClient drops any packet over its buffer.
  const std::string suffix = std::string("/") + p::kTopicVersion + "/" + p::kTopicEstop;
  CHECK(gf::kMaxRootBytes == gf::kMqttBufferBytes - 7 - p::kMaxEstopBytes - suffix.size());
  CHECK(gf::kMaxRootBytes == 234);
  std::string root;
  while (root.size() + 1 + 60 <= gf::kMaxRootBytes) root += (root.empty() ? "" : "/") + std::string(60, 'a');
  root += "/" + std::string(gf::kMaxRootBytes - root.size() - 1, 'b');
  REQUIRE(root.size() == gf::kMaxRootBytes);
  CHECK(gf::isValidRoot(root));
  CHECK_FALSE(gf::isValidRoot(root + "c"));
  gf::DeviceConfig config;
  config.root = root + "c";
  CHECK(config.problem().find("at most 234 bytes") != std::string::npos);
  config.root = root;
  CHECK(config.problem().empty());
}
