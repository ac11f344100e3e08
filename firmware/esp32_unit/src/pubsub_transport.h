// Adapters from the Device's interfaces to PubSubClient, WiFi, Serial and millis() (ESP32
// build; the host builds compile them against the stand-ins in firmware/host_test/).
#pragma once

#include <Arduino.h>
#include <PubSubClient.h>
#include <WiFi.h>
#include <esp_arduino_version.h>
#if ESP_ARDUINO_VERSION_MAJOR >= 3
#include <NetworkClientSecure.h>
#else
#include <WiFiClientSecure.h>
#endif

#include <string>

#include "device.h"
#include "diagnostics.h"
#include "mqtt_watch.h"

namespace gf {

#if ESP_ARDUINO_VERSION_MAJOR >= 3
using SecureClient = NetworkClientSecure;  // 3.x; WiFiClientSecure is its old name
#else
using SecureClient = WiFiClientSecure;
#endif

// What one connection attempt may cost the loop. arduino-esp32's own defaults are 30 s for the
// TCP connect and 120 s for the TLS handshake; PubSubClient's setSocketTimeout bounds only its
// wait for the CONNACK.
constexpr uint32_t kTcpConnectTimeoutMs = 3000;
constexpr uint32_t kTlsHandshakeTimeoutS = 5;  // an ECDSA P-256 handshake takes about 1 s
constexpr uint16_t kMqttAnswerTimeoutS = 2;
constexpr uint32_t kConnectAttemptBoundMs =
    kTcpConnectTimeoutMs + kTlsHandshakeTimeoutS * 1000 + kMqttAnswerTimeoutS * 1000;
constexpr uint16_t kMqttKeepAliveS = 10;

// PubSubClient's settings: empty when done, else why not (setBufferSize allocates, and the
// device must not run with a buffer too small for the stop).
inline std::string configureClient(PubSubClient& client, uint16_t bufferBytes) {
  if (!client.setBufferSize(bufferBytes)) {
    return "no memory for the " + std::to_string(bufferBytes) + "-byte MQTT buffer";
  }
  client.setKeepAlive(kMqttKeepAliveS);
  // connect() then waits at most this long for the broker's CONNACK.
  client.setSocketTimeout(kMqttAnswerTimeoutS);
  return "";
}

// The network client PubSubClient talks through: passes everything on to the WiFi (or TLS)
// client and watches what PubSubClient reads, answering the PUBACK it owes for a QoS 1
// message too large for its buffer (which it drops) and noticing a refusing SUBACK.
class WatchedClient : public Client {
 public:
  // `tls`: the same object as `net` when it is the TLS client (for its error text), else null.
  WatchedClient(WiFiClient& net, SecureClient* tls, size_t bufferBytes)
      : net_(net), tls_(tls), watch_(bufferBytes) {}

  // Open the TCP (and TLS) connection, giving up after `timeoutMs` to connect (and the TLS
  // handshake timeout): PubSubClient's connect() then finds it open and sends CONNECT on it.
  bool open(const char* host, uint16_t port, uint32_t timeoutMs) {
    watch_.reset();
    return net_.connect(host, port, static_cast<int32_t>(timeoutMs)) == 1;
  }
  bool usesTls() const { return tls_ != nullptr; }
  // The TLS client's last error (mbedTLS's words), empty when none.
  std::string tlsError() {
    if (tls_ == nullptr) return "";
    char text[128] = {0};
    const int code = tls_->lastError(text, sizeof text);
    if (code == 0) return "";
    return std::string(text) + " (" + std::to_string(code) + ")";
  }
  const InboundWatch& watch() const { return watch_; }

  int connect(IPAddress ip, uint16_t port) override {
    watch_.reset();
    return net_.connect(ip, port, static_cast<int32_t>(kTcpConnectTimeoutMs));
  }
  int connect(const char* host, uint16_t port) override {
    return open(host, port, kTcpConnectTimeoutMs) ? 1 : 0;
  }
  size_t write(uint8_t b) override { return net_.write(b); }
  size_t write(const uint8_t* buf, size_t size) override { return net_.write(buf, size); }
  int available() override { return net_.available(); }
  int read() override {
    const int b = net_.read();
    if (b >= 0) seen(static_cast<uint8_t>(b));
    return b;
  }
  int read(uint8_t* buf, size_t size) override {
    const int n = net_.read(buf, size);
    for (int i = 0; i < n; ++i) seen(buf[i]);
    return n;
  }
  int peek() override { return net_.peek(); }
  void flush() override { net_.flush(); }
  void stop() override { net_.stop(); }
  uint8_t connected() override { return net_.connected(); }
  operator bool() override { return net_.connected() != 0; }
  using Print::write;

 private:
  void seen(uint8_t b) {
    watch_.feed(b);
    uint16_t id = 0;
    if (watch_.takePuback(id)) {
      // Between two of PubSubClient's packets: it writes each one whole, in one call.
      const uint8_t puback[4] = {0x40, 0x02, static_cast<uint8_t>(id >> 8),
                                 static_cast<uint8_t>(id & 0xFF)};
      net_.write(puback, sizeof puback);
    }
  }

  WiFiClient& net_;
  SecureClient* tls_;
  InboundWatch watch_;
};

// Told when a call may block the loop (a connection attempt), so the sketch can keep the LEDs
// and the button going meanwhile.
class BlockingHook {
 public:
  virtual ~BlockingHook() = default;
  virtual void enter() = 0;
  virtual void leave() = 0;
};

class PubSubTransport : public MqttTransport {
 public:
  // `user` empty: connect without credentials (a broker on a trusted network only). The broker
  // comes with setBroker (the Device's, before each attempt).
  PubSubTransport(PubSubClient& client, WatchedClient& net, const char* user,
                  const char* password)
      : client_(client), net_(net), user_(user), password_(password) {}

  void setBlockingHook(BlockingHook* hook) { hook_ = hook; }

  void setBroker(const Broker& broker) override {
    host_ = broker.host;
    port_ = broker.port;
    // PubSubClient keeps the pointer: host_ lives as long as this transport, unchanged until
    // the next setBroker. Its connect() uses it only when the socket is not open already.
    client_.setServer(host_.c_str(), port_);
  }

  bool connect(const std::string& clientId, const std::string& willTopic,
               const std::string& willPayload) override {
    Blocking blocking(hook_);
    // Always a new session: PubSubClient's connect() returns true and sends nothing while it
    // believes an old one is open.
    net_.stop();
    const unsigned long start = millis();
    if (!net_.open(host_.c_str(), port_, kTcpConnectTimeoutMs)) {
      error_ = std::string(net_.usesTls() ? "no TLS connection" : "no TCP connection") + " to " +
               host_ + ":" + std::to_string(port_) + " after " +
               std::to_string(millis() - start) + " ms (broker down, wrong address or port";
      error_ += net_.usesTls() ? ", or its certificate not signed by GF_MQTT_CA_PEM / not "
                                 "naming its address in GF_MQTT_BROKERS)"
                               : ")";
      const std::string tls = net_.tlsError();
      if (!tls.empty()) error_ += ": " + tls;
      return false;
    }
    // PubSubClient always asks for a clean session; the will goes to the device connection
    // topic, with its QoS (1) and retained.
    const bool login = user_ != nullptr && user_[0] != '\0';
    if (!client_.connect(clientId.c_str(), login ? user_ : nullptr, login ? password_ : nullptr,
                         willTopic.c_str(), proto::kTopicDeviceConnectionQos,
                         proto::kTopicDeviceConnectionRetained, willPayload.c_str())) {
      error_ = mqttStateWords(client_.state());
      net_.stop();
      return false;
    }
    error_.clear();
    return true;
  }
  bool connected() override { return client_.connected(); }
  // Closing the socket without a DISCONNECT: the broker publishes the will.
  void drop() override { net_.stop(); }
  bool subscribe(const std::string& topic, uint8_t qos) override {
    return client_.subscribe(topic.c_str(), qos);
  }
  bool refusedSubscription() override { return net_.watch().refused(); }
  bool publish(const std::string& topic, const std::string& payload, bool retained) override {
    return client_.publish(topic.c_str(), reinterpret_cast<const uint8_t*>(payload.data()),
                           static_cast<unsigned int>(payload.size()), retained);
  }
  void loop() override { client_.loop(); }
  std::string lastError() override { return error_; }

 private:
  struct Blocking {
    explicit Blocking(BlockingHook* hook) : hook_(hook) {
      if (hook_ != nullptr) hook_->enter();
    }
    ~Blocking() {
      if (hook_ != nullptr) hook_->leave();
    }
    Blocking(const Blocking&) = delete;
    Blocking& operator=(const Blocking&) = delete;
    BlockingHook* hook_;
  };

  PubSubClient& client_;
  WatchedClient& net_;
  std::string host_;
  uint16_t port_ = 0;
  const char* user_;
  const char* password_;
  BlockingHook* hook_ = nullptr;
  std::string error_;
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
  std::string status() override { return wifiStatusWords(static_cast<int>(WiFi.status())); }

 private:
  const char* ssid_;
  const char* password_;
};

class ArduinoClock : public Clock {
 public:
  uint32_t nowMs() override { return static_cast<uint32_t>(millis()); }
};

class SerialLog : public Log {
 public:
  void line(const std::string& text) override {
    Serial.print("gridfleet: ");
    Serial.println(text.c_str());
  }
};

}  // namespace gf
