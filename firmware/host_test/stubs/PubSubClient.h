// Host-only stand-in for the PubSubClient calls the sketch uses (signatures only): it records
// what the sketch does and lets a test deliver messages to the callback.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include <WiFi.h>

class PubSubClient {
 public:
  using Callback = std::function<void(char*, uint8_t*, unsigned int)>;
  struct Published {
    std::string topic;
    std::string payload;
    bool retained;
  };

  explicit PubSubClient(Client& net) : network(&net) {}
  PubSubClient& setServer(const char* host, uint16_t port) {
    this->host = host;
    this->port = port;
    return *this;
  }
  PubSubClient& setCallback(Callback cb) {
    callback = std::move(cb);
    return *this;
  }
  bool setBufferSize(uint16_t size) {
    if (!acceptBufferSize) return false;  // as when malloc fails
    bufferSize = size;
    return true;
  }
  PubSubClient& setKeepAlive(uint16_t s) {
    keepAlive = s;
    return *this;
  }
  PubSubClient& setSocketTimeout(uint16_t s) {
    socketTimeout = s;
    return *this;
  }
  // PubSubClient's overload with credentials (null user: none).
  bool connect(const char* id, const char* user, const char* pass, const char* willTopic,
               uint8_t willQos, bool willRetain, const char* willMessage) {
    username = user ? user : "";
    password = pass ? pass : "";
    clientId = id;
    will = willTopic;
    willPayload = willMessage;
    this->willQos = willQos;
    this->willRetain = willRetain;
    isConnected = acceptConnect;
    return isConnected;
  }
  bool connected() {
    if (isConnected && !network->connected()) isConnected = false;
    return isConnected;
  }
  void disconnect() {
    ++disconnects;
    isConnected = false;
  }
  bool subscribe(const char* topic, uint8_t qos) {
    subscriptions.emplace_back(topic, qos);
    return isConnected;
  }
  bool publish(const char* topic, const uint8_t* payload, unsigned int len, bool retained) {
    if (!isConnected) return false;
    published.push_back({topic, std::string(reinterpret_cast<const char*>(payload), len), retained});
    return true;
  }
  bool loop() {
    for (auto& [topic, payload] : inbox) {
      callback(topic.data(), reinterpret_cast<uint8_t*>(payload.data()),
               static_cast<unsigned int>(payload.size()));
    }
    inbox.clear();
    return isConnected;
  }
  int state() { return isConnected ? 0 : -1; }

  // Test side.
  Client* network;  // the client it talks through
  bool acceptBufferSize = true;
  int disconnects = 0;  // clean DISCONNECTs sent
  std::string host;
  uint16_t port = 0;
  uint16_t bufferSize = 256;
  uint16_t keepAlive = 15;
  uint16_t socketTimeout = 15;
  std::string clientId, username, password, will, willPayload;
  uint8_t willQos = 0;
  bool willRetain = false;
  bool isConnected = false;
  bool acceptConnect = true;
  Callback callback;
  std::vector<std::pair<std::string, uint8_t>> subscriptions;
  std::vector<Published> published;
  std::vector<std::pair<std::string, std::string>> inbox;
};
