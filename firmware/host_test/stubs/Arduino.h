// Host-only stand-in for the few Arduino core calls the sketch uses, for a clone without the
// real libraries (../shared/firmware-libs): it records pin activity so the sketch smoke test can
// look at it. Not the Arduino API's code: just the signatures of the calls used.
#pragma once

#include <cstddef>
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
  void println(const char* s) {
    print(s);
    std::fprintf(stderr, "\n");
    atLineStart = true;
  }
  void print(const char* s) {
    std::fprintf(stderr, "%s%s", atLineStart ? "[serial] " : "", s);
    atLineStart = false;
  }
  bool atLineStart = true;
};
inline HostSerial Serial;

// The shape of the Arduino API's Print, Stream and Client (what PubSubClient talks through).
class IPAddress {};
class Print {
 public:
  virtual ~Print() = default;
  virtual size_t write(uint8_t) = 0;
  virtual size_t write(const uint8_t* buf, size_t size) {
    size_t n = 0;
    while (size-- > 0) n += write(*buf++);
    return n;
  }
  virtual void flush() {}
};
class Stream : public Print {
 public:
  virtual int available() = 0;
  virtual int read() = 0;
  virtual int peek() = 0;
};
class Client : public Stream {
 public:
  virtual int connect(IPAddress ip, uint16_t port) = 0;
  virtual int connect(const char* host, uint16_t port) = 0;
  size_t write(uint8_t) override = 0;
  size_t write(const uint8_t* buf, size_t size) override = 0;
  int available() override = 0;
  int read() override = 0;
  virtual int read(uint8_t* buf, size_t size) = 0;
  int peek() override = 0;
  void flush() override = 0;
  virtual void stop() = 0;
  virtual uint8_t connected() = 0;
  virtual operator bool() = 0;
};
