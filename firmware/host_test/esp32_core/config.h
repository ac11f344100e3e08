// Host build against the real libraries: the example configuration, with the brokers, account,
// ids and root from the environment (tests start their brokers on free ports), and TLS (a
// CA-shaped text) when GF_HOST_TLS is set. The brokers: GF_HOST_MQTT_BROKERS (a list, as
// GF_MQTT_BROKERS takes it), else GF_HOST_MQTT_HOST and GF_HOST_MQTT_PORT.
#pragma once
#include "../../esp32_unit/config.example.h"

#include <cstdint>

namespace host {
const char* env(const char* name, const char* fallback);
uint16_t mqttPort();
const char* brokers();
const char* caPem();
}  // namespace host

#undef GF_MQTT_BROKERS
#undef GF_MQTT_USER
#undef GF_MQTT_PASSWORD
#undef GF_UNIT_ID
#undef GF_DEVICE_ID
#undef GF_TOPIC_ROOT
#define GF_MQTT_BROKERS host::brokers()
#define GF_MQTT_CA_PEM host::caPem()
#define GF_MQTT_USER host::env("GF_HOST_MQTT_USER", "")
#define GF_MQTT_PASSWORD host::env("GF_HOST_MQTT_PASSWORD", "")
#define GF_UNIT_ID host::env("GF_HOST_UNIT", "unit1")
#define GF_DEVICE_ID host::env("GF_HOST_DEVICE", "device-unit1")
#define GF_TOPIC_ROOT host::env("GF_HOST_ROOT", "gridfleet")
