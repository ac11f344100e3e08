// gridfleet ESP32 device: four direction LEDs show where its unit is about to move, and a push
// button engages the fleet-wide emergency stop. All behaviour lives in src/ (tested on a PC);
// this file only wires it to WiFi, PubSubClient, the pins and the button interrupt.
#include <Arduino.h>
#include <PubSubClient.h>
#include <Ticker.h>
#include <WiFi.h>

#include <atomic>

#include "config.h"
#include "src/device.h"
#include "src/pubsub_transport.h"
#include "src/tls_config.h"

#ifdef GF_MQTT_BROKERS
const std::string kMqttBrokers = GF_MQTT_BROKERS;
#else  // a config.h from before broker lists: its one broker
const std::string kMqttBrokers = std::string(GF_MQTT_HOST) + ":" + std::to_string(GF_MQTT_PORT);
#endif

WiFiClient wifiClient;
gf::SecureClient secureClient;
// TLS when config.h gives the broker's CA (each broker's certificate must be signed by it and
// name its address in GF_MQTT_BROKERS); plain TCP when GF_MQTT_CA_PEM is empty.
WiFiClient& netClient = gf::chooseClient(wifiClient, secureClient, GF_MQTT_CA_PEM);
gf::WatchedClient watchedClient(netClient, gf::usesTls(GF_MQTT_CA_PEM) ? &secureClient : nullptr,
                                gf::kMqttBufferBytes);
PubSubClient mqttClient(watchedClient);
// The Device tells it which broker of the list before each attempt (PubSubClient's setServer).
gf::PubSubTransport transport(mqttClient, watchedClient, GF_MQTT_USER, GF_MQTT_PASSWORD);
gf::WiFiLink wifiLink(GF_WIFI_SSID, GF_WIFI_PASSWORD);
gf::ArduinoClock arduinoClock;
gf::SerialLog serialLog;
gf::Device* device = nullptr;
bool configOk = false;

// Set by the interrupt, taken by the loop: no network calls and no allocation in the ISR.
std::atomic<bool> buttonEdge{false};

void IRAM_ATTR onButtonFalling() { buttonEdge.store(true); }

void onMqttMessage(char* topic, uint8_t* payload, unsigned int length) {
  if (device != nullptr) device->onMessage(topic, payload, length);
}

gf::DeviceConfig makeConfig() {
  gf::DeviceConfig config;
  config.root = GF_TOPIC_ROOT;
  config.unit = GF_UNIT_ID;
  config.device = GF_DEVICE_ID;
  config.debounceMs = GF_DEBOUNCE_MS;
  config.stopRetryMs = GF_STOP_RETRY_MS;
  config.mqttBackoffInitialMs = GF_MQTT_BACKOFF_INITIAL_MS;
  config.mqttBackoffMaxMs = GF_MQTT_BACKOFF_MAX_MS;
  return config;
}

void showLeds(const gf::Leds& leds) {
  digitalWrite(GF_PIN_LED_N, leds.n ? HIGH : LOW);
  digitalWrite(GF_PIN_LED_E, leds.e ? HIGH : LOW);
  digitalWrite(GF_PIN_LED_S, leds.s ? HIGH : LOW);
  digitalWrite(GF_PIN_LED_W, leds.w ? HIGH : LOW);
}

// A connection attempt blocks loop() for up to gf::kConnectAttemptBoundMs (TCP connect, TLS
// handshake, CONNACK). Meanwhile this timer (in the esp_timer task) runs the LEDs: the offline
// chase, or the stop pattern as soon as the button is pressed; the loop takes the press itself
// from the interrupt's flag once the attempt returns.
Ticker ledTicker;
constexpr uint32_t kLedTickMs = 50;
std::atomic<bool> connecting{false};
std::atomic<bool> stopWhileConnecting{false};

void showLedsWhileConnecting() {
  if (!connecting.load()) return;
  if (buttonEdge.load() || digitalRead(GF_PIN_BUTTON) == LOW) stopWhileConnecting.store(true);
  showLeds(gf::ledsFor(gf::Direction::None, stopWhileConnecting.load(), false, millis()));
}

class LedsWhileConnecting : public gf::BlockingHook {
 public:
  void enter() override {
    stopWhileConnecting.store(device != nullptr && device->showsStop());
    connecting.store(true);
    showLedsWhileConnecting();  // at once, not a timer period later
  }
  void leave() override { connecting.store(false); }
};
LedsWhileConnecting ledsWhileConnecting;

void setup() {
  Serial.begin(115200);
  pinMode(GF_PIN_LED_N, OUTPUT);
  pinMode(GF_PIN_LED_E, OUTPUT);
  pinMode(GF_PIN_LED_S, OUTPUT);
  pinMode(GF_PIN_LED_W, OUTPUT);
  pinMode(GF_PIN_BUTTON, INPUT_PULLUP);
  attachInterrupt(digitalPinToInterrupt(GF_PIN_BUTTON), onButtonFalling, FALLING);

  static gf::DeviceConfig config = makeConfig();
  std::string problem =
      gf::parseBrokers(kMqttBrokers, gf::usesTls(GF_MQTT_CA_PEM), config.brokers);
  if (problem.empty()) problem = config.problem();
  if (problem.empty()) problem = gf::caProblem(GF_MQTT_CA_PEM);
  // Room for the longest estop (512 bytes) with its topic and header; larger ones are dropped.
  if (problem.empty()) problem = gf::configureClient(mqttClient, gf::kMqttBufferBytes);
  if (!problem.empty()) {
    Serial.println(("gridfleet: config.h: " + problem).c_str());
    return;  // loop() then blinks the stop pattern and does nothing else
  }
  configOk = true;
  WiFi.setAutoReconnect(true);
  transport.setBroker(config.brokers.front());  // the Device sets it again before each attempt
  mqttClient.setCallback(onMqttMessage);
  if (gf::usesTls(GF_MQTT_CA_PEM)) secureClient.setHandshakeTimeout(gf::kTlsHandshakeTimeoutS);
  transport.setBlockingHook(&ledsWhileConnecting);
  ledTicker.attach_ms(kLedTickMs, showLedsWhileConnecting);
  static gf::Device dev(config, transport, wifiLink, arduinoClock, &serialLog);
  device = &dev;
  Serial.println(("gridfleet: device " + config.device + " shows unit " + config.unit +
                  (config.brokers.size() > 1 ? ", brokers " : ", broker ") +
                  gf::brokerNames(config.brokers) +
                  (gf::usesTls(GF_MQTT_CA_PEM) ? " (TLS)" : " (plain TCP)"))
                     .c_str());
}

void loop() {
  if (!configOk) {
    showLeds(gf::ledsFor(gf::Direction::None, true, false, millis()));
    return;
  }
  bool edge = buttonEdge.exchange(false);
  bool pressed = digitalRead(GF_PIN_BUTTON) == LOW;  // pull-up: pressed reads LOW
  device->tick(edge, pressed);
  showLeds(device->leds());
}
