// Host stand-in for arduino-esp32's TLS client (2.x WiFiClientSecure, 3.x NetworkClientSecure),
// with its defaults: 30 s to connect and 120 s for the handshake unless told otherwise. The host
// has no mbedTLS: after the TCP connect it sends the start of a ClientHello and waits, as a real
// handshake does, for the server's answer, at most the handshake timeout; it never completes
// TLS (an answer fails it too), which is what the tests of a dead TLS broker need.
#pragma once

#include <WiFi.h>

#if ESP_ARDUINO_VERSION_MAJOR >= 3
#define GF_HOST_SECURE_CLIENT NetworkClientSecure
#else
#define GF_HOST_SECURE_CLIENT WiFiClientSecure
#endif

class GF_HOST_SECURE_CLIENT : public GF_HOST_LWIP_CLIENT {
 public:
  GF_HOST_SECURE_CLIENT() { timeout_ = 30000; }
  int connect(IPAddress ip, uint16_t port) override;
  int connect(IPAddress ip, uint16_t port, int32_t timeout) override;
  int connect(const char* host, uint16_t port) override;
  int connect(const char* host, uint16_t port, int32_t timeout) override;
  void setCACert(const char* rootCA) { ca_ = rootCA; }
  void setHandshakeTimeout(unsigned long handshake_timeout) {
    handshakeTimeoutMs_ = handshake_timeout * 1000;
  }
  int lastError(char* buf, const size_t size);
  using GF_HOST_LWIP_CLIENT::write;

 private:
  const char* ca_ = nullptr;
  unsigned long handshakeTimeoutMs_ = 120000;
  int lastError_ = 0;
};
