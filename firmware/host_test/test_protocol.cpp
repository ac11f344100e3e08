#include <doctest/doctest.h>

#include <string>

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
