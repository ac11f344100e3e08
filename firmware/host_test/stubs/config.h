// Host build only: the sketch smoke test uses the example configuration, with a CA-shaped text
// in place of the example's placeholder (which the device refuses) so the TLS path runs, and a
// list of two brokers (a cluster's), so the sketch's move from one to the next runs.
#pragma once
#include "../../esp32_unit/config.example.h"

// The example's own CA text, for the test that its placeholder is refused.
static const char* const kExampleCaPem = GF_MQTT_CA_PEM;
#define GF_MQTT_CA_PEM "-----BEGIN CERTIFICATE-----\nMIIBdTCCARugAwIBAgIU\n-----END CERTIFICATE-----\n"

// The example's own broker first, then a second node (its default port: TLS's).
static const char* const kExampleBrokers = GF_MQTT_BROKERS;
#undef GF_MQTT_BROKERS
#define GF_MQTT_BROKERS "192.168.1.10:8883, mqtts://192.168.1.11"
