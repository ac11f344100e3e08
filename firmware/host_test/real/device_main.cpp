// The sketch as a host program, against the real PubSubClient and ArduinoCore-API: runs setup()
// and loop() over real sockets, for tests/device/test_firmware_real.py. Configured by the environment
// (host_test/esp32_core/config.h). Reads commands on stdin: `press` (the button goes down and its
// interrupt fires), `release`, `wifi down`, `wifi up`, `quit`. Writes lines on stdout: `[serial]
// ...` (what the sketch prints), `leds NESW <ms>` whenever the LED pins change (`.` for off),
// `pressed <ms>` when the button goes down, `stall <took ms> <end ms>` for a loop() pass that took
// longer than 200 ms, and `ready <bound ms>` at start (times are millis()).
#include <Arduino.h>
#include <config.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <iostream>
#include <string>
#include <thread>

#include "../../esp32_unit/src/pubsub_transport.h"

void setup();
void loop();

namespace {
std::atomic<bool> quit{false};

std::string ledsNow() {
  std::string s;
  s += host::pinOut(GF_PIN_LED_N) ? 'N' : '.';
  s += host::pinOut(GF_PIN_LED_E) ? 'E' : '.';
  s += host::pinOut(GF_PIN_LED_S) ? 'S' : '.';
  s += host::pinOut(GF_PIN_LED_W) ? 'W' : '.';
  return s;
}

void say(const std::string& line) {
  std::printf("%s\n", line.c_str());
  std::fflush(stdout);
}

// Watches the LED pins as a person would, every few milliseconds, whoever drives them.
void watchLeds() {
  std::string last;
  while (!quit.load()) {
    const std::string now = ledsNow();
    if (now != last) {
      say("leds " + now + " " + std::to_string(millis()));
      last = now;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

void readCommands() {
  std::string line;
  while (std::getline(std::cin, line)) {
    if (line == "press") {
      host::setPinIn(GF_PIN_BUTTON, LOW);
      host::interrupt(GF_PIN_BUTTON);
      say("pressed " + std::to_string(millis()));
    } else if (line == "release") {
      host::setPinIn(GF_PIN_BUTTON, HIGH);
    } else if (line == "wifi down") {
      host::setWifiUp(false);
    } else if (line == "wifi up") {
      host::setWifiUp(true);
    } else if (line == "quit") {
      break;
    }
  }
  quit.store(true);
}
}  // namespace

int main() {
  setup();
  say("ready " + std::to_string(gf::kConnectAttemptBoundMs));
  std::thread leds(watchLeds);
  std::thread commands(readCommands);
  commands.detach();  // blocked in getline until stdin closes
  while (!quit.load()) {
    const unsigned long start = millis();
    loop();
    const unsigned long took = millis() - start;
    if (took > 200) say("stall " + std::to_string(took) + " " + std::to_string(start + took));
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  leds.join();
  return 0;
}
