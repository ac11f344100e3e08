// Host-only stand-in for arduino-esp32 2.x's WiFiClientSecure (signatures only): records its
// CA and its handshake timeout.
#pragma once

#include <cstring>
#include <string>

#include <WiFi.h>

class WiFiClientSecure : public WiFiClient {
 public:
  void setCACert(const char* pem) {
    caCert = pem;
    ++caCertCalls;
  }
  void setHandshakeTimeout(unsigned long seconds) { handshakeTimeoutS = seconds; }
  int lastError(char* buf, const size_t size) {
    if (size > 0) buf[0] = '\0';
    return 0;
  }
  std::string caCert;
  int caCertCalls = 0;
  unsigned long handshakeTimeoutS = 120;  // arduino-esp32's default
};
