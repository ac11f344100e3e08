// Host build only: the sketch smoke test uses the example configuration, with a CA-shaped text
// in place of the example's placeholder (which the device refuses) so the TLS path runs.
#pragma once
#include "../../esp32_unit/config.example.h"

// The example's own CA text, for the test that its placeholder is refused.
static const char* const kExampleCaPem = GF_MQTT_CA_PEM;
#define GF_MQTT_CA_PEM "-----BEGIN CERTIFICATE-----\nMIIBdTCCARugAwIBAgIU\n-----END CERTIFICATE-----\n"
