// Adapters from the Device's interfaces to PubSubClient, WiFi and millis() (ESP32 build; the
// host build compiles them against the stand-in headers in firmware/host_test/stubs/).
#pragma once

#include <Arduino.h>
#include <PubSubClient.h>
#include <WiFi.h>

#include "device.h"

namespace gf {

class PubSubTransport : public MqttTransport {
 public:
  // `user` empty: connect without credentials (a broker on a trusted network only).
  PubSubTransport(PubSubClient& client, const char* user, const char* password)
      : client_(client), user_(user), password_(password) {}

  bool connect(const std::string& clientId, const std::string& willTopic,
               const std::string& willPayload) override {
    // PubSubClient always asks for a clean session; the will goes to the device connection
    // topic, with its QoS (1) and retained.
    const bool login = user_ != nullptr && user_[0] != '\0';
    return client_.connect(clientId.c_str(), login ? user_ : nullptr, login ? password_ : nullptr,
                           willTopic.c_str(), proto::kTopicDeviceConnectionQos,
                           proto::kTopicDeviceConnectionRetained, willPayload.c_str());
  }
  bool connected() override { return client_.connected(); }
  void disconnect() override { client_.disconnect(); }
  bool subscribe(const std::string& topic, uint8_t qos) override {
    return client_.subscribe(topic.c_str(), qos);
  }
  bool publish(const std::string& topic, const std::string& payload, bool retained) override {
    return client_.publish(topic.c_str(), reinterpret_cast<const uint8_t*>(payload.data()),
                           static_cast<unsigned int>(payload.size()), retained);
  }
  void loop() override { client_.loop(); }

 private:
  PubSubClient& client_;
  const char* user_;
  const char* password_;
};

class WiFiLink : public NetLink {
 public:
  WiFiLink(const char* ssid, const char* password) : ssid_(ssid), password_(password) {}
  bool up() override { return WiFi.status() == WL_CONNECTED; }
  void begin() override {
    WiFi.mode(WIFI_STA);
    WiFi.disconnect();
    WiFi.begin(ssid_, password_);  // returns at once; the ESP32 joins in the background
  }

 private:
  const char* ssid_;
  const char* password_;
};

class ArduinoClock : public Clock {
 public:
  uint32_t nowMs() override { return static_cast<uint32_t>(millis()); }
};

}  // namespace gf
