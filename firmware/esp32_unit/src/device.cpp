#include "device.h"

namespace gf {

std::string DeviceConfig::problem() const {
  if (!isValidRoot(root)) return "topic root '" + root + "' is not valid";
  if (!isValidId(unit)) return "unit id '" + unit + "' is not a valid id";
  if (!isValidId(device)) return "device id '" + device + "' is not a valid id";
  return "";
}

Device::Device(const DeviceConfig& config, MqttTransport& mqtt, NetLink& link, Clock& clock)
    : config_(config),
      mqtt_(mqtt),
      link_(link),
      clock_(clock),
      directionTopic_(gf::directionTopic(config.root, config.unit)),
      estopTopic_(gf::estopTopic(config.root)),
      pressTopic_(deviceStopTopic(config.root, config.device)),
      connectionTopic_(deviceConnectionTopic(config.root, config.device)),
      stopPayload_(buttonEstopPayload(config.device)),
      debouncer_(config.debounceMs),
      mqttBackoff_(config.mqttBackoffInitialMs, config.mqttBackoffMaxMs),
      linkBackoff_(config.linkBackoffInitialMs, config.linkBackoffMaxMs),
      stop_(config.stopRetryMs) {}

void Device::tick(bool buttonEdge, bool buttonPressed) {
  const uint32_t now = clock_.nowMs();
  // The button first: a press is recorded whatever the network is doing.
  if (debouncer_.update(buttonEdge, buttonPressed, now)) stop_.press();

  if (!link_.up()) {
    if (online_) lost();
    // WiFi.begin() returns at once; give each try time to join before starting over.
    if (!linkStarted_ || uint32_t(now - linkStartMs_) >= linkWaitMs_) {
      link_.begin();
      linkStarted_ = true;
      linkStartMs_ = now;
      linkWaitMs_ = linkBackoff_.next();
    }
    return;
  }
  linkBackoff_.reset();
  linkStarted_ = false;

  if (online_ && !mqtt_.connected()) lost();
  if (!online_) connectIfDue(now);
  if (!online_) return;

  mqtt_.loop();  // may deliver messages, may find the connection gone
  if (!mqtt_.connected()) {
    lost();
    return;
  }
  if (stop_.due(now) && mqtt_.publish(pressTopic_, stopPayload_, proto::kTopicDeviceStopRetained)) {
    stop_.sent(now);
  }
}

void Device::connectIfDue(uint32_t now) {
  if (attempted_ && uint32_t(now - lastAttemptMs_) < waitMs_) return;
  attempted_ = true;
  lastAttemptMs_ = now;
  ++connectAttempts_;
  if (!mqtt_.connect(config_.device, connectionTopic_, proto::kDeviceWill)) {
    waitMs_ = mqttBackoff_.next();
    return;
  }
  bool ok = mqtt_.publish(connectionTopic_, proto::kDeviceOnline,
                          proto::kTopicDeviceConnectionRetained);
  // Each at its topic's QoS: direction is high-rate, 0 (amqtt upgrades delivery to the
  // subscription's QoS); the stop 1.
  ok = ok && mqtt_.subscribe(directionTopic_, proto::kTopicDirectionQos);
  ok = ok && mqtt_.subscribe(estopTopic_, proto::kTopicEstopQos);
  ok = ok && mqtt_.subscribe(pressTopic_, proto::kTopicDeviceStopQos);
  if (!ok) {
    // A half-set-up session would miss the stop: drop it and try again later.
    mqtt_.disconnect();
    waitMs_ = mqttBackoff_.next();
    return;
  }
  mqttBackoff_.reset();
  waitMs_ = 0;
  online_ = true;
}

void Device::lost() {
  online_ = false;
  // Read afresh on the next session: a press cleared meanwhile is not replayed, one held is.
  pressed_ = false;
  stop_.connectionLost();
  // Reconnect at once the first time; the back-off grows only with failed attempts.
  attempted_ = false;
}

void Device::onMessage(const std::string& topic, const uint8_t* payload, size_t len) {
  if (topic == directionTopic_) {
    Direction d;
    if (parseDirection(payload, len, d)) direction_ = d;
    return;
  }
  if (topic == estopTopic_) {
    EstopKind kind = parseEstop(payload, len);
    if (kind == EstopKind::Invalid) return;
    estopEngaged_ = kind == EstopKind::Engaged;
    return;
  }
  if (topic == pressTopic_) {
    // Our own press back from the broker: it has it. Empty: an operator's release cleared it.
    if (len == 0) {
      pressed_ = false;
    } else if (payload != nullptr && len == stopPayload_.size() &&
               stopPayload_.compare(0, len, reinterpret_cast<const char*>(payload), len) == 0) {
      pressed_ = true;
      stop_.confirmed();
    }
  }
}

Leds Device::leds() const {
  return ledsFor(direction_, estopEngaged_ || pressed_ || stop_.pending(), online_, clock_.nowMs());
}

}  // namespace gf
