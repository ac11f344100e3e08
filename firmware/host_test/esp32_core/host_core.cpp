// The host side of the ESP32 board stand-ins: clock, pins, Serial, WiFi status, the Ticker
// thread and the TCP client on POSIX sockets.
#include <Arduino.h>
#include <NetworkClientSecure.h>
#include <Ticker.h>
#include <WiFi.h>
#include <WiFiClientSecure.h>
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <string>
#include <thread>

#include "config.h"

namespace {
const auto kStart = std::chrono::steady_clock::now();
std::array<std::atomic<int>, host::kPins> pinOutState{};
std::array<std::atomic<int>, host::kPins> pinInState{};
std::array<std::atomic<int>, host::kPins> pinModeState{};
std::array<std::atomic<void (*)()>, host::kPins> isrs{};
std::atomic<bool> pinsReady{false};
std::atomic<bool> wifiUp{true};
std::atomic<bool> wifiBegun{false};
std::mutex serialMutex;
std::string serialLine;

void initPins() {
  bool expected = false;
  if (!pinsReady.compare_exchange_strong(expected, true)) return;
  for (auto& p : pinInState) p.store(HIGH);  // pull-ups: released
}

bool valid(int pin) { return pin >= 0 && pin < host::kPins; }
}  // namespace

extern "C" {
unsigned long millis() {
  return static_cast<unsigned long>(std::chrono::duration_cast<std::chrono::milliseconds>(
                                        std::chrono::steady_clock::now() - kStart)
                                        .count());
}
void delay(uint32_t ms) { std::this_thread::sleep_for(std::chrono::milliseconds(ms)); }
void yield(void) { std::this_thread::yield(); }
}

void pinMode(uint8_t pin, uint8_t mode) {
  initPins();
  if (valid(pin)) pinModeState[pin].store(mode);
}
void digitalWrite(uint8_t pin, uint8_t val) {
  if (valid(pin)) pinOutState[pin].store(val);
}
int digitalRead(uint8_t pin) {
  initPins();
  return valid(pin) ? pinInState[pin].load() : LOW;
}
void attachInterrupt(uint8_t pin, void (*handler)(void), int /*mode*/) {
  if (valid(pin)) isrs[pin].store(handler);
}

namespace host {
int pinOut(int pin) { return valid(pin) ? pinOutState[pin].load() : LOW; }
int pinModeOf(int pin) { return valid(pin) ? pinModeState[pin].load() : 0; }
void setPinIn(int pin, int level) {
  initPins();
  if (valid(pin)) pinInState[pin].store(level);
}
void interrupt(int pin) {
  if (!valid(pin)) return;
  void (*handler)() = isrs[pin].load();
  if (handler != nullptr) handler();
}
bool hasInterrupt(int pin) { return valid(pin) && isrs[pin].load() != nullptr; }
void setWifiUp(bool up) { wifiUp.store(up); }

const char* env(const char* name, const char* fallback) {
  const char* value = std::getenv(name);
  return value != nullptr ? value : fallback;
}
uint16_t mqttPort() { return static_cast<uint16_t>(std::atoi(env("GF_HOST_MQTT_PORT", "1883"))); }
const char* brokers() {
  static const std::string kOne =
      std::string(env("GF_HOST_MQTT_HOST", "127.0.0.1")) + ":" + std::to_string(mqttPort());
  return env("GF_HOST_MQTT_BROKERS", kOne.c_str());
}
const char* caPem() {
  // Shaped like a PEM certificate: the host's TLS stand-in never reads it.
  static const char kPem[] =
      "-----BEGIN CERTIFICATE-----\nMIIBdTCCARugAwIBAgIU\n-----END CERTIFICATE-----\n";
  return env("GF_HOST_TLS", "")[0] != '\0' ? kPem : "";
}
}  // namespace host

HardwareSerial Serial;

void HardwareSerial::begin(unsigned long /*baud*/) {}

size_t HardwareSerial::write(uint8_t c) { return write(&c, 1); }

size_t HardwareSerial::write(const uint8_t* buffer, size_t size) {
  std::lock_guard<std::mutex> lock(serialMutex);
  for (size_t i = 0; i < size; ++i) {
    const char c = static_cast<char>(buffer[i]);
    if (c == '\n') {
      std::printf("[serial] %s\n", serialLine.c_str());
      std::fflush(stdout);
      serialLine.clear();
    } else if (c != '\r') {
      serialLine += c;
    }
  }
  return size;
}

WiFiClass WiFi;

wl_status_t WiFiClass::begin(const char*, const char*, int32_t, const uint8_t*, bool) {
  wifiBegun.store(true);
  return status();
}
wl_status_t WiFiClass::status() {
  if (!wifiBegun.load()) return WL_IDLE_STATUS;
  return wifiUp.load() ? WL_CONNECTED : WL_NO_SSID_AVAIL;
}
bool WiFiClass::mode(wifi_mode_t) { return true; }
bool WiFiClass::disconnect(bool, bool) { return true; }
bool WiFiClass::setAutoReconnect(bool) { return true; }

void Ticker::attach_ms(uint32_t milliseconds, void (*callback)()) {
  detach();
  running_.store(true);
  thread_ = std::thread([this, milliseconds, callback] {
    while (running_.load()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(milliseconds));
      if (running_.load()) callback();
    }
  });
}

void Ticker::detach() {
  running_.store(false);
  if (thread_.joinable()) thread_.join();
}

GF_HOST_LWIP_CLIENT::~GF_HOST_LWIP_CLIENT() { stop(); }

int GF_HOST_LWIP_CLIENT::openSocket(const char* host, uint16_t port, int timeoutMs) {
  addrinfo hints{};
  hints.ai_family = AF_INET;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  if (getaddrinfo(host, std::to_string(port).c_str(), &hints, &found) != 0 || found == nullptr) {
    return -1;
  }
  int fd = socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) {
    freeaddrinfo(found);
    return -1;
  }
  fcntl(fd, F_SETFL, fcntl(fd, F_GETFL, 0) | O_NONBLOCK);
  int res = ::connect(fd, found->ai_addr, found->ai_addrlen);
  freeaddrinfo(found);
  if (res < 0 && errno == EINPROGRESS) {
    pollfd p{fd, POLLOUT, 0};
    res = poll(&p, 1, timeoutMs < 0 ? -1 : timeoutMs) == 1 ? 0 : -1;
    int err = 0;
    socklen_t len = sizeof err;
    if (res == 0 && (getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &len) != 0 || err != 0)) res = -1;
  }
  if (res < 0) {
    ::close(fd);
    return -1;
  }
  int one = 1;
  setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  return fd;
}

int GF_HOST_LWIP_CLIENT::connect(IPAddress ip, uint16_t port) {
  return connect(ip, port, timeout_);
}
int GF_HOST_LWIP_CLIENT::connect(IPAddress ip, uint16_t port, int32_t timeout_ms) {
  return connect(ip.toString().c_str(), port, timeout_ms);
}
int GF_HOST_LWIP_CLIENT::connect(const char* host, uint16_t port) {
  return connect(host, port, timeout_);
}
int GF_HOST_LWIP_CLIENT::connect(const char* host, uint16_t port, int32_t timeout_ms) {
  stop();
  timeout_ = timeout_ms;
  fd_ = openSocket(host, port, timeout_ms);
  return fd_ >= 0 ? 1 : 0;
}

size_t GF_HOST_LWIP_CLIENT::write(uint8_t data) { return write(&data, 1); }

size_t GF_HOST_LWIP_CLIENT::write(const uint8_t* buf, size_t size) {
  size_t sent = 0;
  while (fd_ >= 0 && sent < size) {
    const ssize_t n = ::send(fd_, buf + sent, size - sent, MSG_NOSIGNAL);
    if (n > 0) {
      sent += size_t(n);
    } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
      pollfd p{fd_, POLLOUT, 0};
      if (poll(&p, 1, timeout_) != 1) break;
    } else {
      stop();
    }
  }
  return sent;
}

int GF_HOST_LWIP_CLIENT::available() {
  if (fd_ < 0) return 0;
  int n = 0;
  if (ioctl(fd_, FIONREAD, &n) == 0 && n > 0) return n;
  // Nothing yet: wait a moment, so PubSubClient's busy waits do not spin a host core.
  pollfd p{fd_, POLLIN, 0};
  if (poll(&p, 1, 1) == 1 && ioctl(fd_, FIONREAD, &n) == 0 && n > 0) return n;
  return 0;
}

int GF_HOST_LWIP_CLIENT::read() {
  uint8_t b = 0;
  return read(&b, 1) == 1 ? b : -1;
}

int GF_HOST_LWIP_CLIENT::read(uint8_t* buf, size_t size) {
  if (fd_ < 0) return -1;
  const ssize_t n = ::recv(fd_, buf, size, MSG_DONTWAIT);
  if (n == 0) {
    stop();  // the peer closed
    return -1;
  }
  return n < 0 ? -1 : int(n);
}

int GF_HOST_LWIP_CLIENT::peek() {
  uint8_t b = 0;
  if (fd_ < 0) return -1;
  return ::recv(fd_, &b, 1, MSG_PEEK | MSG_DONTWAIT) == 1 ? b : -1;
}

void GF_HOST_LWIP_CLIENT::stop() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

uint8_t GF_HOST_LWIP_CLIENT::connected() {
  if (fd_ < 0) return 0;
  uint8_t b = 0;
  const ssize_t n = ::recv(fd_, &b, 1, MSG_PEEK | MSG_DONTWAIT);
  if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) {
    stop();
    return 0;
  }
  return 1;
}

int GF_HOST_SECURE_CLIENT::connect(IPAddress ip, uint16_t port) {
  return connect(ip.toString().c_str(), port, timeout_);
}
int GF_HOST_SECURE_CLIENT::connect(IPAddress ip, uint16_t port, int32_t timeout) {
  return connect(ip.toString().c_str(), port, timeout);
}
int GF_HOST_SECURE_CLIENT::connect(const char* host, uint16_t port) {
  return connect(host, port, timeout_);
}
int GF_HOST_SECURE_CLIENT::connect(const char* host, uint16_t port, int32_t timeout) {
  stop();
  timeout_ = timeout;
  const int fd = openSocket(host, port, timeout);
  if (fd < 0) {
    lastError_ = -0x0052;  // MBEDTLS_ERR_NET_CONNECT_FAILED
    return 0;
  }
  // The start of a ClientHello (a handshake record header), then the wait for the ServerHello.
  const uint8_t hello[5] = {0x16, 0x03, 0x01, 0x00, 0x00};
  (void)::send(fd, hello, sizeof hello, MSG_NOSIGNAL);
  pollfd p{fd, POLLIN, 0};
  const int answered = poll(&p, 1, int(handshakeTimeoutMs_));
  ::close(fd);
  lastError_ = answered == 1 ? -0x7780   // MBEDTLS_ERR_SSL_FATAL_ALERT_MESSAGE: no TLS here
                             : -0x6800;  // MBEDTLS_ERR_SSL_TIMEOUT
  return 0;
}

int GF_HOST_SECURE_CLIENT::lastError(char* buf, const size_t size) {
  const char* text = lastError_ == -0x6800   ? "SSL - The operation timed out"
                     : lastError_ == -0x0052 ? "NET - The connection to the given server / port failed"
                     : lastError_ != 0       ? "SSL - A fatal alert message was received from our peer"
                                             : "";
  if (size > 0) std::snprintf(buf, size, "%s", text);
  return lastError_;
}

// The C functions ArduinoCore-API's String expects from the board core (itoa.h, dtostrf.h):
// arduino-esp32 has them in its stdlib_noniso; these are the host's own.
namespace {
char* unsignedToText(unsigned long value, char* out, int radix, bool negative) {
  char digits[sizeof(unsigned long) * 8 + 1];
  int n = 0;
  do {
    const unsigned long d = value % unsigned(radix);
    digits[n++] = char(d < 10 ? '0' + d : 'a' + d - 10);
    value /= unsigned(radix);
  } while (value > 0);
  char* p = out;
  if (negative) *p++ = '-';
  while (n > 0) *p++ = digits[--n];
  *p = '\0';
  return out;
}
}  // namespace

extern "C" {
char* ltoa(long value, char* out, int radix) {
  const bool negative = value < 0 && radix == 10;
  const unsigned long magnitude =
      negative ? 0UL - static_cast<unsigned long>(value) : static_cast<unsigned long>(value);
  return unsignedToText(magnitude, out, radix, negative);
}
char* itoa(int value, char* out, int radix) { return ltoa(value, out, radix); }
char* ultoa(unsigned long value, char* out, int radix) {
  return unsignedToText(value, out, radix, false);
}
char* utoa(unsigned value, char* out, int radix) { return unsignedToText(value, out, radix, false); }
char* dtostrf(double val, signed char width, unsigned char prec, char* sout) {
  std::sprintf(sout, "%*.*f", int(width), int(prec), val);
  return sout;
}
}
