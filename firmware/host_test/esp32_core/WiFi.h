// Host stand-in for arduino-esp32's WiFi.h: the WiFi status (the harness switches it), and a
// WiFiClient that is a real TCP client (POSIX sockets) behind the real ArduinoCore-API Client
// interface, with arduino-esp32's class layout: 2.x `WiFiClient : ESPLwIPClient`, 3.x
// `NetworkClient : ESPLwIPClient` with `WiFiClient` its typedef.
#pragma once

#include <Arduino.h>
#include <esp_arduino_version.h>

typedef enum {
  WL_NO_SHIELD = 255,
  WL_STOPPED = 254,
  WL_IDLE_STATUS = 0,
  WL_NO_SSID_AVAIL = 1,
  WL_SCAN_COMPLETED = 2,
  WL_CONNECTED = 3,
  WL_CONNECT_FAILED = 4,
  WL_CONNECTION_LOST = 5,
  WL_DISCONNECTED = 6
} wl_status_t;

typedef enum { WIFI_MODE_NULL = 0, WIFI_MODE_STA, WIFI_MODE_AP, WIFI_MODE_APSTA } wifi_mode_t;
#define WIFI_OFF WIFI_MODE_NULL
#define WIFI_STA WIFI_MODE_STA

class WiFiClass {
 public:
  wl_status_t begin(const char* ssid, const char* passphrase = nullptr, int32_t channel = 0,
                    const uint8_t* bssid = nullptr, bool connect = true);
  static wl_status_t status();
  bool mode(wifi_mode_t m);
  bool disconnect(bool wifioff = false, bool eraseap = false);
  bool setAutoReconnect(bool autoReconnect);
};
extern WiFiClass WiFi;

namespace host {
void setWifiUp(bool up);  // the access point comes and goes
}  // namespace host

class ESPLwIPClient : public Client {
 public:
  virtual int connect(IPAddress ip, uint16_t port, int32_t timeout) = 0;
  virtual int connect(const char* host, uint16_t port, int32_t timeout) = 0;
#if ESP_ARDUINO_VERSION_MAJOR >= 3
  virtual void setConnectionTimeout(uint32_t milliseconds) = 0;
#else
  virtual int setTimeout(uint32_t seconds) = 0;
#endif
};

#if ESP_ARDUINO_VERSION_MAJOR >= 3
#define GF_HOST_LWIP_CLIENT NetworkClient
#else
#define GF_HOST_LWIP_CLIENT WiFiClient
#endif

class GF_HOST_LWIP_CLIENT : public ESPLwIPClient {
 public:
  GF_HOST_LWIP_CLIENT() = default;
  ~GF_HOST_LWIP_CLIENT();  // not virtual: the Arduino API's Print has no virtual destructor
  GF_HOST_LWIP_CLIENT(const GF_HOST_LWIP_CLIENT&) = delete;
  GF_HOST_LWIP_CLIENT& operator=(const GF_HOST_LWIP_CLIENT&) = delete;

  int connect(IPAddress ip, uint16_t port) override;
  int connect(IPAddress ip, uint16_t port, int32_t timeout_ms) override;
  int connect(const char* host, uint16_t port) override;
  int connect(const char* host, uint16_t port, int32_t timeout_ms) override;
  size_t write(uint8_t data) override;
  size_t write(const uint8_t* buf, size_t size) override;
  int available() override;
  int read() override;
  int read(uint8_t* buf, size_t size) override;
  int peek() override;
  void flush() override {}
  void stop() override;
  uint8_t connected() override;
  operator bool() override { return connected() != 0; }
#if ESP_ARDUINO_VERSION_MAJOR >= 3
  void setConnectionTimeout(uint32_t milliseconds) override { timeout_ = int(milliseconds); }
#else
  int setTimeout(uint32_t seconds) override {
    timeout_ = int(seconds * 1000);
    return 0;
  }
#endif
  using Print::write;

 protected:
  // A TCP connection to host:port within timeoutMs; the socket, or -1.
  int openSocket(const char* host, uint16_t port, int timeoutMs);
  int fd_ = -1;
  int timeout_ = 3000;  // arduino-esp32's WIFI_CLIENT_DEF_CONN_TIMEOUT_MS
};

#if ESP_ARDUINO_VERSION_MAJOR >= 3
typedef NetworkClient WiFiClient;
#endif
