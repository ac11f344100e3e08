// What the device says on Serial about its connections: PubSubClient's state() and the WiFi
// status in words, so a wrong password, a refused certificate and an unreachable broker can be
// told apart on the serial monitor.
#pragma once

#include <string>

namespace gf {

// PubSubClient::state() (its MQTT_* values: -4 to 5) in words.
std::string mqttStateWords(int state);
// arduino-esp32's WiFi.status() (wl_status_t) in words.
std::string wifiStatusWords(int status);

}  // namespace gf
