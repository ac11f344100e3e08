// gridfleet ESP32 device: copy this file to config.h (git-ignored) and fill it in.
#pragma once

// WiFi (2.4 GHz; the ESP32 cannot join 5 GHz networks).
#define GF_WIFI_SSID "your-network"
#define GF_WIFI_PASSWORD "your-password"

// MQTT broker: `host:port`, the LAN address of the machine running `gridfleet broker` (not
// 127.0.0.1: that would be the ESP32 itself). With TLS (below) port 8883, and the broker's
// certificate must be made for this address: `gridfleet accounts tls --out DIR --host 127.0.0.1
// --host 192.168.1.10`. A cluster of brokers: each node, comma-separated, e.g.
// "192.168.1.10:8883,192.168.1.11:8883": the device is on one at a time, moves to the next when
// its broker is lost or refuses it, and backs off (GF_MQTT_BACKOFF_*) only once every broker of
// the list has failed. An item may also be `mqtt://host:port` (no CA below) or
// `mqtts://host:port` (with one); the port defaults to 8883 with TLS, 1883 without.
#define GF_MQTT_BROKERS "192.168.1.10:8883"

// The CA that signed the broker's certificate: the whole of DIR/ca.pem from `gridfleet accounts
// tls`, BEGIN and END lines included (it is public; the key stays on the broker). The device
// then connects with TLS and refuses a broker that CA did not vouch for. R"PEM()PEM" (empty)
// instead: plain TCP MQTT (port 1883), readable by anyone on the network.
// Paste it between the PEM( and )PEM markers as it is, line breaks and all.
static const char GF_MQTT_CA_PEM[] = R"PEM(-----BEGIN CERTIFICATE-----
paste the lines of ca.pem here
-----END CERTIFICATE-----
)PEM";

// This device's broker account, from the fleet's accounts file (`gridfleet accounts init`
// makes `device-<unit>` for each unit; its password is in that file). Empty user: none.
#define GF_MQTT_USER "device-unit1"
#define GF_MQTT_PASSWORD "password-from-the-accounts-file"

// Which unit's direction to show, this device's own id (its MQTT client id and the `<by>` of
// its stop), and the topic root (`--root` of the other components; default "gridfleet").
// Ids: 1-64 letters, digits, '_', '.', '-', starting with a letter or digit.
#define GF_UNIT_ID "unit1"
#define GF_DEVICE_ID "device-unit1"
#define GF_TOPIC_ROOT "gridfleet"

// GPIO pins (ESP32 DevKit numbering). LEDs are active high through a series resistor; the
// button connects its pin to GND and uses the internal pull-up (an external 10 kOhm is better).
#define GF_PIN_LED_N 25
#define GF_PIN_LED_E 26
#define GF_PIN_LED_S 27
#define GF_PIN_LED_W 14
#define GF_PIN_BUTTON 33

// Timing (milliseconds).
#define GF_DEBOUNCE_MS 50
#define GF_STOP_RETRY_MS 2000
#define GF_MQTT_BACKOFF_INITIAL_MS 500
#define GF_MQTT_BACKOFF_MAX_MS 30000
