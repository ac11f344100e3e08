// Host-only stand-in for the few Arduino core calls the sketch uses; it records pin activity
// so the sketch smoke test can look at it. Not the Arduino API's code: just its signatures.
#pragma once

#include <cstdint>
#include <cstdio>
#include <map>

#define IRAM_ATTR
#define HIGH 1
#define LOW 0
#define INPUT 0x01
#define OUTPUT 0x03
#define INPUT_PULLUP 0x05
#define FALLING 0x02
#define CHANGE 0x03

using byte = uint8_t;
using boolean = bool;

namespace host {
inline uint32_t nowMs = 0;
inline std::map<int, int> pinMode;
inline std::map<int, int> pinOut;
inline std::map<int, int> pinIn;  // what digitalRead returns (default HIGH: pull-up, released)
inline std::map<int, void (*)()> isr;
}  // namespace host

inline unsigned long millis() { return host::nowMs; }
inline void delay(unsigned long ms) { host::nowMs += static_cast<uint32_t>(ms); }
inline void pinMode(uint8_t pin, uint8_t mode) { host::pinMode[pin] = mode; }
inline void digitalWrite(uint8_t pin, uint8_t value) { host::pinOut[pin] = value; }
inline int digitalRead(uint8_t pin) {
  auto it = host::pinIn.find(pin);
  return it == host::pinIn.end() ? HIGH : it->second;
}
inline int digitalPinToInterrupt(uint8_t pin) { return pin; }
inline void attachInterrupt(int irq, void (*fn)(), int /*mode*/) { host::isr[irq] = fn; }

struct HostSerial {
  void begin(unsigned long) {}
  void println(const char* s) { std::fprintf(stderr, "[serial] %s\n", s); }
  void print(const char* s) { std::fprintf(stderr, "%s", s); }
};
inline HostSerial Serial;
