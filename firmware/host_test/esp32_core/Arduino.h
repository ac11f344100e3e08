// Host stand-in for arduino-esp32's Arduino.h, for building the sketch against the real
// libraries: the Arduino API classes (Print, Stream, Client, IPAddress, String) are the real
// ArduinoCore-API's, from FIRMWARE_LIBS; the board's own part (GPIO, interrupts, millis, Serial)
// is declared here with arduino-esp32's signatures and runs on the host (host_core.cpp): pins are
// atomics, so the LED timer's thread and the loop can both use them.
#pragma once

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "Client.h"
#include "IPAddress.h"
#include "Print.h"
#include "Stream.h"
#include "String.h"

// arduino-esp32's cores build on these names without the namespace.
using namespace arduino;

#define IRAM_ATTR
#define LOW 0x0
#define HIGH 0x1
#define INPUT 0x01
#define OUTPUT 0x03
#define PULLUP 0x04
#define INPUT_PULLUP 0x05
#define RISING 0x01
#define FALLING 0x02
#define CHANGE 0x03
#define digitalPinToInterrupt(p) (p)

typedef bool boolean;
typedef uint8_t byte;

extern "C" {
unsigned long millis();
void delay(uint32_t ms);
void yield(void);
}
void pinMode(uint8_t pin, uint8_t mode);
void digitalWrite(uint8_t pin, uint8_t val);
int digitalRead(uint8_t pin);
void attachInterrupt(uint8_t pin, void (*handler)(void), int mode);

// Serial: the real Print, writing to stdout one line at a time.
class HardwareSerial : public Print {
 public:
  void begin(unsigned long baud);
  size_t write(uint8_t c) override;
  size_t write(const uint8_t* buffer, size_t size) override;
  using Print::write;
};
extern HardwareSerial Serial;

// The host's side of the board: what the harness and tests drive and read.
namespace host {
constexpr int kPins = 64;
int pinOut(int pin);
int pinModeOf(int pin);
void setPinIn(int pin, int level);
void interrupt(int pin);  // the pin's interrupt fires (as its edge would)
bool hasInterrupt(int pin);
}  // namespace host
