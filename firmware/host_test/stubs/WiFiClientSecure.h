// Host-only stand-in for arduino-esp32's WiFiClientSecure (signatures only): records its CA.
#pragma once

#include <string>

#include <WiFi.h>

class WiFiClientSecure : public WiFiClient {
 public:
  void setCACert(const char* pem) {
    caCert = pem;
    ++caCertCalls;
  }
  std::string caCert;
  int caCertCalls = 0;
};
