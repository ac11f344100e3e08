// Host-only stand-in for the ESP32 WiFi calls the sketch uses (signatures only).
#pragma once

#include <string>

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

class WiFiClient {};
