// Runs the real esp32_unit.ino (compiled against the stand-in headers) through setup() and
// loop(): the wiring of pins, interrupt, WiFi and PubSubClient to the Device.
#include <doctest/doctest.h>

#include <Arduino.h>
#include <PubSubClient.h>
#include <Ticker.h>
#include <WiFi.h>
#include <WiFiClientSecure.h>
#include <config.h>

#include <set>

#include <string>
#include <utility>
#include <vector>

#include "../esp32_unit/src/protocol_table.h"

void setup();
void loop();
extern PubSubClient mqttClient;
extern Ticker ledTicker;
extern WiFiClientSecure secureClient;

namespace {
const std::string kRoot = GF_TOPIC_ROOT;
const std::string kDir = kRoot + "/v1/units/" GF_UNIT_ID "/direction";
const std::string kPress = kRoot + "/v1/devices/" GF_DEVICE_ID "/stop";

void loops(int n) {
  for (int i = 0; i < n; ++i) {
    loop();
    host::nowMs += 1;
  }
}
}  // namespace

TEST_CASE("the sketch wires pins, WiFi, PubSubClient and the button to the device") {
  setup();
  CHECK(host::pinMode[GF_PIN_LED_N] == OUTPUT);
  CHECK(host::pinMode[GF_PIN_LED_W] == OUTPUT);
  CHECK(host::pinMode[GF_PIN_BUTTON] == INPUT_PULLUP);
  REQUIRE(host::isr.count(GF_PIN_BUTTON) == 1);
  // The first broker of config.h's list (the stand-in's: two, host_test/stubs/config.h).
  CHECK(mqttClient.host == "192.168.1.10");
  CHECK(mqttClient.port == 8883);
  CHECK(mqttClient.bufferSize >= 512 + 100);

  loops(3);  // joins WiFi, connects MQTT
  CHECK(WiFi.begins == 1);
  CHECK(WiFi.lastSsid == GF_WIFI_SSID);
  REQUIRE(mqttClient.connected());
  CHECK(mqttClient.clientId == GF_DEVICE_ID);
  CHECK(mqttClient.will == kRoot + "/v1/devices/" GF_DEVICE_ID "/connection");
  CHECK(mqttClient.willPayload == "broken");
  // It logs in with its account from config.h: the broker's ACL knows it by that name.
  CHECK(mqttClient.username == GF_MQTT_USER);
  CHECK(mqttClient.password == GF_MQTT_PASSWORD);
  CHECK(mqttClient.clientId == GF_DEVICE_ID);
  CHECK(mqttClient.willQos == 1);
  CHECK(mqttClient.willRetain);

  mqttClient.inbox.emplace_back(kDir, "E");
  loops(2);
  CHECK(host::pinOut[GF_PIN_LED_E] == HIGH);
  CHECK(host::pinOut[GF_PIN_LED_N] == LOW);
  CHECK(host::pinOut[GF_PIN_LED_S] == LOW);
  CHECK(host::pinOut[GF_PIN_LED_W] == LOW);

  // The button: the interrupt only sets a flag; the loop publishes, retained.
  host::pinIn[GF_PIN_BUTTON] = LOW;
  const auto publishedBefore = mqttClient.published.size();
  host::isr[GF_PIN_BUTTON]();
  host::isr[GF_PIN_BUTTON]();  // a bounce
  CHECK(mqttClient.published.size() == publishedBefore);  // nothing sent from the interrupt
  loops(100);
  host::pinIn[GF_PIN_BUTTON] = HIGH;
  loops(100);
  int stops = 0;
  for (const auto& m : mqttClient.published) {
    if (m.topic == kPress) {
      ++stops;
      CHECK(m.payload == "engaged|" GF_DEVICE_ID "|button");
      CHECK(m.retained);
    }
  }
  CHECK(stops == 1);

  // All of it through the real PubSubClient adapter, as the generated protocol_table.h says.
  namespace p = gf::proto;
  const std::string prefix = kRoot + "/" + p::kTopicVersion + "/";
  const std::string sep(1, p::kEstopSeparator);
  CHECK(mqttClient.subscriptions ==
        std::vector<std::pair<std::string, uint8_t>>{
            {prefix + p::kTopicDirectionBefore + GF_UNIT_ID + p::kTopicDirectionAfter,
             p::kSubscribeQos},
            {prefix + p::kTopicEstop, p::kSubscribeQos},
            {prefix + p::kTopicDeviceStopBefore + GF_DEVICE_ID + p::kTopicDeviceStopAfter,
             p::kSubscribeQos}});
  CHECK(mqttClient.will ==
        prefix + p::kTopicDeviceConnectionBefore + GF_DEVICE_ID + p::kTopicDeviceConnectionAfter);
  CHECK(mqttClient.willPayload == p::kDeviceWill);
  CHECK(mqttClient.willQos == p::kTopicDeviceConnectionQos);
  CHECK(mqttClient.willRetain == p::kTopicDeviceConnectionRetained);
  REQUIRE(mqttClient.published.size() >= 2);
  CHECK(mqttClient.published.front().topic == mqttClient.will);
  CHECK(mqttClient.published.front().payload == p::kDeviceOnline);
  CHECK(mqttClient.published.back().payload ==
        p::kEstopEngaged + sep + GF_DEVICE_ID + sep + p::kEstopButtonReason);
  CHECK(mqttClient.bufferSize >= p::kMaxEstopBytes + 100);
}

TEST_CASE("while a connection attempt blocks, a timer runs the LEDs and shows a press at once") {
  // The sketch is set up and connected (the test above); the broker connection now breaks.
  REQUIRE(mqttClient.connected());
  REQUIRE(static_cast<bool>(ledTicker.fire));
  CHECK(ledTicker.periodMs <= 100);
  host::pinIn[GF_PIN_BUTTON] = HIGH;
  loops(300);  // the earlier press settles
  mqttClient.inbox.emplace_back(kRoot + "/v1/fleet/estop", "released|dashboard|ok");
  mqttClient.inbox.emplace_back(kPress, "engaged|" GF_DEVICE_ID "|button");  // it has the press
  mqttClient.inbox.emplace_back(kPress, "");  // and an operator's release cleared it
  loops(2);
  const auto ledsNow = [] {
    return std::string(1, host::pinOut[GF_PIN_LED_N] ? 'N' : '.') +
           (host::pinOut[GF_PIN_LED_E] ? 'E' : '.') + (host::pinOut[GF_PIN_LED_S] ? 'S' : '.') +
           (host::pinOut[GF_PIN_LED_W] ? 'W' : '.');
  };
  std::set<std::string> chase;
  std::set<std::string> afterPress;
  int stopsBefore = 0;
  for (const auto& m : mqttClient.published) stopsBefore += m.topic == kPress;
  int blocked = 0;
  host::duringConnect = [&] {
    // The loop is stuck in connect(): only the timer runs, every periodMs.
    ++blocked;
    for (int i = 0; i < 20; ++i) {
      host::nowMs += ledTicker.periodMs;
      ledTicker.fire();
      chase.insert(ledsNow());
    }
    host::pinIn[GF_PIN_BUTTON] = LOW;
    host::isr[GF_PIN_BUTTON]();
    for (int i = 0; i < 20; ++i) {
      host::nowMs += ledTicker.periodMs;
      ledTicker.fire();
      afterPress.insert(ledsNow());
    }
    host::pinIn[GF_PIN_BUTTON] = HIGH;
  };
  secureClient.open = false;  // the broker went away
  loops(3);
  host::duringConnect = nullptr;
  REQUIRE(blocked == 1);
  // Its broker lost, the sketch went to the next of the list: PubSubClient and the TLS client
  // were both told (setServer, and the connection the transport opens itself).
  CHECK(secureClient.lastHost == "192.168.1.11");
  CHECK(secureClient.lastPort == 8883);  // mqtts:// without a port: TLS's
  CHECK(mqttClient.host == "192.168.1.11");
  CHECK(mqttClient.connected());
  // The offline chase ran round (one LED at a time), and the press showed the stop blink.
  CHECK(chase == std::set<std::string>{"N...", ".E..", "..S.", "...W"});
  CHECK(afterPress == std::set<std::string>{"NESW", "...."});
  // Once connect() returned, the loop took the press from the interrupt's flag and sent it.
  loops(5);
  int stopsAfter = 0;
  for (const auto& m : mqttClient.published) stopsAfter += m.topic == kPress;
  CHECK(stopsAfter == stopsBefore + 1);
}
