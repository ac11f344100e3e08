// The device's behaviour with the network and the clock injected: the .ino only wires it to
// WiFi, PubSubClient, the LED pins and the button interrupt.
#pragma once

#include <cstdint>
#include <string>

#include <vector>

#include "brokers.h"
#include "leds.h"
#include "protocol.h"
#include "timing.h"

namespace gf {

// An MQTT 3.1.1 client (PubSubClient on the ESP32, a fake in the host tests).
class MqttTransport {
 public:
  virtual ~MqttTransport() = default;
  // Where the next connect() goes (one broker of the configured list).
  virtual void setBroker(const Broker& broker) = 0;
  // Connect with clean session and a last will (QoS 1, retained); true when connected.
  virtual bool connect(const std::string& clientId, const std::string& willTopic,
                       const std::string& willPayload) = 0;
  virtual bool connected() = 0;
  // Close the connection without a DISCONNECT, so the broker publishes the will (`broken`).
  virtual void drop() = 0;
  // True when the SUBSCRIBE was written (PubSubClient does not wait for the SUBACK).
  virtual bool subscribe(const std::string& topic, uint8_t qos) = 0;
  // The broker's SUBACK refused a subscription of this session.
  virtual bool refusedSubscription() = 0;
  // QoS 0 (all PubSubClient can send); true when handed to the socket.
  virtual bool publish(const std::string& topic, const std::string& payload, bool retained) = 0;
  // Pump the connection: incoming messages reach Device::onMessage from here.
  virtual void loop() = 0;
  // Why the last connect() failed, in words.
  virtual std::string lastError() = 0;
};

// Where the device says what it is doing and why a connection failed (Serial on the ESP32).
class Log {
 public:
  virtual ~Log() = default;
  virtual void line(const std::string& text) = 0;
};

// The network link under MQTT (WiFi on the ESP32).
class NetLink {
 public:
  virtual ~NetLink() = default;
  virtual bool up() = 0;
  // Start (or restart) joining the network; must not block.
  virtual void begin() = 0;
  // The link's state in words (for the log).
  virtual std::string status() = 0;
};

class Clock {
 public:
  virtual ~Clock() = default;
  virtual uint32_t nowMs() = 0;  // wraps like millis()
};

struct DeviceConfig {
  // The brokers, in order (parseBrokers; one, or the nodes of a cluster).
  std::vector<Broker> brokers = std::vector<Broker>(1, Broker("127.0.0.1", kMqttPort));
  std::string root = proto::kDefaultRoot;
  std::string unit = "unit1";
  std::string device = "device-unit1";
  uint32_t debounceMs = 50;
  uint32_t stopRetryMs = 2000;
  uint32_t mqttBackoffInitialMs = 500;
  uint32_t mqttBackoffMaxMs = 30000;
  uint32_t linkBackoffInitialMs = 10000;
  uint32_t linkBackoffMaxMs = 60000;

  // Empty when usable, else what is wrong (ids and root as protocol.md defines them).
  std::string problem() const;
};

class Device {
 public:
  Device(const DeviceConfig& config, MqttTransport& mqtt, NetLink& link, Clock& clock,
         Log* log = nullptr);

  // One pass of the main loop: `buttonEdge` is the interrupt's flag (taken and cleared by the
  // caller), `buttonPressed` the pin level now.
  void tick(bool buttonEdge, bool buttonPressed);
  // Every message the MQTT client receives; anything unexpected or malformed changes nothing.
  void onMessage(const std::string& topic, const uint8_t* payload, size_t len);

  Leds leds() const;  // what the LEDs should show now
  // The stop pattern is due: the fleet's latch, this device's press, or one not yet confirmed.
  bool showsStop() const { return estopEngaged_ || pressed_ || stop_.pending(); }
  bool online() const { return online_; }
  Direction direction() const { return direction_; }
  bool estopEngaged() const { return estopEngaged_; }  // the fleet's latch says engaged
  bool pressed() const { return pressed_; }  // the broker holds this device's press
  bool stopPending() const { return stop_.pending(); }
  uint32_t connectAttempts() const { return connectAttempts_; }
  // The broker the device is on, or tries next.
  const Broker& broker() const { return config_.brokers[rotation_.current()]; }
  const std::string& directionTopic() const { return directionTopic_; }
  const std::string& estopTopic() const { return estopTopic_; }
  const std::string& pressTopic() const { return pressTopic_; }
  const std::string& connectionTopic() const { return connectionTopic_; }
  const std::string& stopPayload() const { return stopPayload_; }

 private:
  void connectIfDue(uint32_t now);
  // The session is over; `brokerLost`: its broker's fault (not WiFi's), so on to the next one.
  void lost(bool brokerLost);
  // Give up this session without a DISCONNECT (the will stays) and try again after back-off.
  void abandon(uint32_t now, const std::string& why);
  // An attempt on this broker failed (`why`): the next broker at once, or after back-off once
  // every broker of the list has failed.
  void retry(const std::string& why);
  // " (broker host:port)"-like words naming `broker` when there is a list of them; "" with one.
  std::string naming(const std::string& before, const Broker& broker, const std::string& after) const;
  void say(const std::string& text);

  DeviceConfig config_;
  MqttTransport& mqtt_;
  NetLink& link_;
  Clock& clock_;
  Log* log_;
  std::string directionTopic_;
  std::string estopTopic_;
  std::string pressTopic_;
  std::string connectionTopic_;
  std::string stopPayload_;
  Debouncer debouncer_;
  Backoff mqttBackoff_;
  BrokerRotation rotation_;
  Backoff linkBackoff_;
  PendingStop stop_;
  bool online_ = false;
  bool attempted_ = false;
  uint32_t lastAttemptMs_ = 0;
  uint32_t waitMs_ = 0;
  bool linkStarted_ = false;
  bool linkWasUp_ = false;
  uint32_t linkStartMs_ = 0;
  uint32_t linkWaitMs_ = 0;
  uint32_t connectAttempts_ = 0;
  Direction direction_ = Direction::None;
  bool estopEngaged_ = false;
  bool pressed_ = false;
};

}  // namespace gf
