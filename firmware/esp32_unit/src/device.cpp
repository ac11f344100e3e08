#include "device.h"

namespace gf {

std::string DeviceConfig::problem() const {
  if (brokers.empty()) return "no broker in GF_MQTT_BROKERS";
  if (!isValidRoot(root)) {
    return "topic root '" + root + "' is not valid ('/'-separated ids, at most " +
           std::to_string(kMaxRootBytes) + " bytes, so that the longest stop fits the " +
           std::to_string(kMqttBufferBytes) + "-byte MQTT buffer)";
  }
  if (!isValidId(unit)) return "unit id '" + unit + "' is not a valid id";
  if (!isValidId(device)) return "device id '" + device + "' is not a valid id";
  return "";
}

Device::Device(const DeviceConfig& config, MqttTransport& mqtt, NetLink& link, Clock& clock,
               Log* log)
    : config_(config),
      mqtt_(mqtt),
      link_(link),
      clock_(clock),
      log_(log),
      directionTopic_(gf::directionTopic(config.root, config.unit)),
      estopTopic_(gf::estopTopic(config.root)),
      pressTopic_(deviceStopTopic(config.root, config.device)),
      connectionTopic_(deviceConnectionTopic(config.root, config.device)),
      stopPayload_(buttonEstopPayload(config.device)),
      debouncer_(config.debounceMs),
      mqttBackoff_(config.mqttBackoffInitialMs, config.mqttBackoffMaxMs),
      rotation_(config.brokers.size()),
      linkBackoff_(config.linkBackoffInitialMs, config.linkBackoffMaxMs),
      stop_(config.stopRetryMs) {}

void Device::tick(bool buttonEdge, bool buttonPressed) {
  const uint32_t now = clock_.nowMs();
  // The button first: a press is recorded whatever the network is doing.
  if (debouncer_.update(buttonEdge, buttonPressed, now)) stop_.press();

  if (!link_.up()) {
    if (linkWasUp_) say("WiFi: lost (" + link_.status() + ")");
    linkWasUp_ = false;
    if (online_) lost(false);  // WiFi's doing: the same broker when it is back
    // WiFi.begin() returns at once; give each try time to join before starting over.
    if (!linkStarted_ || uint32_t(now - linkStartMs_) >= linkWaitMs_) {
      if (linkStarted_) say("WiFi: not joined yet (" + link_.status() + "); joining again");
      link_.begin();
      linkStarted_ = true;
      linkStartMs_ = now;
      linkWaitMs_ = linkBackoff_.next();
    }
    return;
  }
  if (!linkWasUp_) say("WiFi: connected");
  linkWasUp_ = true;
  linkBackoff_.reset();
  linkStarted_ = false;

  if (online_ && !mqtt_.connected()) lost(true);
  if (!online_) connectIfDue(now);
  if (!online_) return;

  mqtt_.loop();  // may deliver messages, may find the connection gone
  if (!mqtt_.connected()) {
    lost(true);
    return;
  }
  if (mqtt_.refusedSubscription()) {
    // The broker said no to a topic (its ACL): without it the device would miss stops.
    abandon(now, "the broker refused a subscription (does this account's ACL allow reading " +
                     directionTopic_ + ", " + estopTopic_ + " and " + pressTopic_ + "?)");
    return;
  }
  if (stop_.due(now) && mqtt_.publish(pressTopic_, stopPayload_, proto::kTopicDeviceStopRetained)) {
    stop_.sent(now);
  }
}

void Device::connectIfDue(uint32_t now) {
  if (attempted_ && uint32_t(now - lastAttemptMs_) < waitMs_) return;
  if (config_.brokers.empty()) return;  // a configuration problem (DeviceConfig::problem)
  attempted_ = true;
  lastAttemptMs_ = now;
  ++connectAttempts_;
  const Broker target = broker();
  mqtt_.setBroker(target);
  if (!mqtt_.connect(config_.device, connectionTopic_, proto::kDeviceWill)) {
    // The wait runs from the attempt's end: one against a dead TLS broker blocks for seconds,
    // and measured from its start the next would follow at once.
    lastAttemptMs_ = clock_.nowMs();
    retry("connect failed" + naming(" at broker ", target, "") + ": " + mqtt_.lastError());
    return;
  }
  bool ok = mqtt_.publish(connectionTopic_, proto::kDeviceOnline,
                          proto::kTopicDeviceConnectionRetained);
  // Every subscription at kSubscribeQos (protocol.md §2): a clean session gains nothing from
  // more, and on RabbitMQ 3.10 a QoS 1 one would pin the device to its broker's node.
  ok = ok && mqtt_.subscribe(directionTopic_, proto::kSubscribeQos);
  ok = ok && mqtt_.subscribe(estopTopic_, proto::kSubscribeQos);
  ok = ok && mqtt_.subscribe(pressTopic_, proto::kSubscribeQos);
  if (!ok) {
    // A half-set-up session would miss the stop: drop it (no DISCONNECT: the broker then
    // replaces the `online` just sent with the will) and try again later.
    mqtt_.drop();
    retry("could not send the subscriptions" + naming(" to broker ", target, ""));
    return;
  }
  mqttBackoff_.reset();
  rotation_.connected();
  waitMs_ = 0;
  online_ = true;
  say("MQTT: connected as " + config_.device + naming(" to broker ", target, "") + ", showing " +
      directionTopic_);
}

void Device::retry(const std::string& why) {
  const bool atOnce = rotation_.failed();  // with one broker: never, always the back-off
  waitMs_ = atOnce ? 0 : mqttBackoff_.next();
  std::string next = atOnce ? "trying broker " + broker().name() + " at once"
                            : "next try in " + std::to_string(waitMs_) + " ms";
  if (!atOnce && config_.brokers.size() > 1) {
    next = "every broker failed; " + next + ", at broker " + broker().name();
  }
  say("MQTT: " + why + "; " + next);
}

void Device::abandon(uint32_t now, const std::string& why) {
  const Broker was = broker();
  lost(false);
  attempted_ = true;
  lastAttemptMs_ = now;
  retry(why + naming(" (broker ", was, ")"));
}

std::string Device::naming(const std::string& before, const Broker& broker,
                           const std::string& after) const {
  if (config_.brokers.size() < 2) return "";
  return before + broker.name() + after;
}

void Device::say(const std::string& text) {
  if (log_ != nullptr) log_->line(text);
}

void Device::lost(bool brokerLost) {
  if (online_) {
    std::string words = "MQTT: connection lost" + naming(" (broker ", broker(), ")");
    if (brokerLost && config_.brokers.size() > 1) {
      rotation_.lost();  // on to the next broker, at once (a new round of the list)
      words += "; trying broker " + broker().name();
    }
    say(words);
  }
  // Close what is left of the old session: PubSubClient's connect() would otherwise reuse a
  // socket that still looks open (after a WiFi drop) and send no new CONNECT.
  mqtt_.drop();
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
  return ledsFor(direction_, showsStop(), online_, clock_.nowMs());
}

}  // namespace gf
