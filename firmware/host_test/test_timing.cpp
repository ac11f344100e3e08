#include <doctest/doctest.h>

#include "../esp32_unit/src/leds.h"
#include "../esp32_unit/src/timing.h"

TEST_CASE("each direction lights exactly its LED, none for '-'") {
  using gf::Direction;
  for (uint32_t t : {0u, 100u, 260u, 777u}) {
    gf::Leds n = gf::ledsFor(Direction::N, false, true, t);
    gf::Leds e = gf::ledsFor(Direction::E, false, true, t);
    gf::Leds s = gf::ledsFor(Direction::S, false, true, t);
    gf::Leds w = gf::ledsFor(Direction::W, false, true, t);
    CHECK((n.n && n.count() == 1));
    CHECK((e.e && e.count() == 1));
    CHECK((s.s && s.count() == 1));
    CHECK((w.w && w.count() == 1));
    CHECK(gf::ledsFor(Direction::None, false, true, t).count() == 0);
  }
}

TEST_CASE("the stop pattern wins over direction and over offline: all four blink") {
  for (auto d : {gf::Direction::N, gf::Direction::E, gf::Direction::S, gf::Direction::W,
                 gf::Direction::None}) {
    for (bool online : {true, false}) {
      CHECK(gf::ledsFor(d, true, online, 0).count() == 4);
      CHECK(gf::ledsFor(d, true, online, gf::kBlinkHalfPeriodMs).count() == 0);
      CHECK(gf::ledsFor(d, true, online, 2 * gf::kBlinkHalfPeriodMs + 1).count() == 4);
    }
  }
}

TEST_CASE("offline: one LED runs round, whatever the stale direction") {
  gf::Leds a = gf::ledsFor(gf::Direction::E, false, false, 0);
  gf::Leds b = gf::ledsFor(gf::Direction::E, false, false, gf::kChaseStepMs);
  gf::Leds c = gf::ledsFor(gf::Direction::E, false, false, 2 * gf::kChaseStepMs);
  CHECK((a.count() == 1 && a.n));
  CHECK((b.count() == 1 && b.e));
  CHECK((c.count() == 1 && c.s));
}

TEST_CASE("debouncer: a bouncy press and release count once") {
  gf::Debouncer d(50);
  uint32_t t = 0;
  int presses = 0;
  // Press with 8 bounces 1 ms apart, held 200 ms, released with 6 bounces.
  for (int i = 0; i < 8; ++i) presses += d.update(true, i % 2 == 0, t++);
  for (int i = 0; i < 200; ++i) presses += d.update(false, true, t++);
  for (int i = 0; i < 6; ++i) presses += d.update(true, i % 2 == 1, t++);
  for (int i = 0; i < 100; ++i) presses += d.update(false, false, t++);
  CHECK(presses == 1);
  // The next real press counts again.
  CHECK(d.update(true, true, t++));
}

TEST_CASE("debouncer: a press shorter than one loop pass is still seen through the edge flag") {
  gf::Debouncer d(50);
  CHECK(d.update(true, false, 10));
  CHECK_FALSE(d.update(false, false, 20));
  CHECK_FALSE(d.update(false, false, 59));  // quiet for 49 ms only
  CHECK_FALSE(d.update(true, false, 59));   // a late bounce restarts the quiet period
  CHECK_FALSE(d.update(false, false, 108));
  CHECK_FALSE(d.update(true, true, 108));
  CHECK_FALSE(d.update(false, false, 130));
  CHECK_FALSE(d.update(false, false, 157));
  CHECK_FALSE(d.update(false, false, 158));  // re-armed now, but no press yet
  CHECK(d.update(true, true, 159));
}

TEST_CASE("debouncer works across the millis() wrap") {
  gf::Debouncer d(50);
  uint32_t t = 0xFFFFFFF0u;
  CHECK(d.update(true, true, t));
  CHECK_FALSE(d.update(false, false, t + 10));
  CHECK_FALSE(d.update(false, false, t + 70));  // wrapped past 0: re-armed
  CHECK(d.update(true, true, t + 71));
}

TEST_CASE("back-off doubles and caps, and starts over after reset") {
  gf::Backoff b(500, 30000);
  CHECK(b.next() == 500);
  CHECK(b.next() == 1000);
  CHECK(b.next() == 2000);
  CHECK(b.next() == 4000);
  CHECK(b.next() == 8000);
  CHECK(b.next() == 16000);
  CHECK(b.next() == 30000);
  CHECK(b.next() == 30000);
  b.reset();
  CHECK(b.next() == 500);
}

TEST_CASE("pending stop: due until confirmed, retried after retryMs and after reconnect") {
  gf::PendingStop s(2000);
  CHECK_FALSE(s.due(0));
  s.press();
  CHECK(s.due(0));
  s.sent(0);
  CHECK_FALSE(s.due(1999));
  CHECK(s.due(2000));
  s.sent(2000);
  s.connectionLost();
  CHECK(s.due(2001));
  s.press();  // a second press while pending is the same stop
  s.confirmed();
  CHECK_FALSE(s.pending());
  CHECK_FALSE(s.due(99999));
}
