// Host-only stand-in for the ESP32 WiFi calls the sketch uses (signatures of arduino-esp32
// 2.x): no network; the client records how it was asked to connect.
#pragma once

#include <functional>
#include <string>

#include <Arduino.h>

enum wl_status_t { WL_IDLE_STATUS = 0, WL_CONNECTED = 3, WL_DISCONNECTED = 6 };
enum wifi_mode_t { WIFI_OFF = 0, WIFI_STA = 1 };

class HostWiFi {
 public:
  wl_status_t status() { return joined ? WL_CONNECTED : WL_DISCONNECTED; }
  bool mode(wifi_mode_t) { return true; }
  bool disconnect() { return true; }
  bool setAutoReconnect(bool) { return true; }
  void begin(const char* ssid, const char* /*password*/) {
    ++begins;
    lastSsid = ssid;
    joined = joinOnBegin;
  }
  bool joined = false;
  bool joinOnBegin = true;
  int begins = 0;
  std::string lastSsid;
};
inline HostWiFi WiFi;

namespace host {
// Runs inside every client connect: what a test does while the loop is blocked there.
inline std::function<void()> duringConnect;
}  // namespace host

// arduino-esp32 2.x: ESPLwIPClient adds the connects with a timeout (milliseconds).
class ESPLwIPClient : public Client {
 public:
  virtual int connect(IPAddress ip, uint16_t port, int32_t timeout) = 0;
  virtual int connect(const char* host, uint16_t port, int32_t timeout) = 0;
  using Client::connect;
};

class WiFiClient : public ESPLwIPClient {
 public:
  int connect(IPAddress, uint16_t port) override { return connect("ip", port, 30000); }
  int connect(const char* host, uint16_t port) override { return connect(host, port, 30000); }
  int connect(IPAddress, uint16_t port, int32_t timeout) override {
    return connect("ip", port, timeout);
  }
  int connect(const char* host, uint16_t port, int32_t timeout) override {
    lastHost = host;
    lastPort = port;
    lastTimeoutMs = timeout;
    ++connects;
    if (host::duringConnect) host::duringConnect();
    open = true;
    return 1;
  }
  size_t write(uint8_t) override { return 1; }
  size_t write(const uint8_t*, size_t size) override { return size; }
  int available() override { return 0; }
  int read() override { return -1; }
  int read(uint8_t*, size_t) override { return -1; }
  int peek() override { return -1; }
  void flush() override {}
  void stop() override { open = false; }
  uint8_t connected() override { return open ? 1 : 0; }
  operator bool() override { return open; }

  std::string lastHost;
  uint16_t lastPort = 0;
  int32_t lastTimeoutMs = 0;
  int connects = 0;
  bool open = false;
};
