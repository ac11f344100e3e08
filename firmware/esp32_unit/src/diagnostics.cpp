#include "diagnostics.h"

namespace gf {

std::string mqttStateWords(int state) {
  switch (state) {
    case -4: return "the broker did not answer CONNECT in time (MQTT_CONNECTION_TIMEOUT)";
    case -3: return "the connection was lost (MQTT_CONNECTION_LOST)";
    case -2: return "no network connection to the broker (MQTT_CONNECT_FAILED)";
    case -1: return "disconnected (MQTT_DISCONNECTED)";
    case 0: return "connected (MQTT_CONNECTED)";
    case 1: return "the broker refused MQTT 3.1.1 (MQTT_CONNECT_BAD_PROTOCOL)";
    case 2: return "the broker refused the client id (MQTT_CONNECT_BAD_CLIENT_ID)";
    case 3: return "the broker is unavailable (MQTT_CONNECT_UNAVAILABLE)";
    case 4:
      return "the broker refused the user name or password: check GF_MQTT_USER and "
             "GF_MQTT_PASSWORD (MQTT_CONNECT_BAD_CREDENTIALS)";
    case 5:
      return "the broker does not authorise this account (MQTT_CONNECT_UNAUTHORIZED)";
    default: return "PubSubClient state " + std::to_string(state);
  }
}

std::string wifiStatusWords(int status) {
  switch (status) {
    case 0: return "idle (WL_IDLE_STATUS)";
    case 1: return "the network GF_WIFI_SSID is not in range (WL_NO_SSID_AVAIL)";
    case 2: return "scan completed (WL_SCAN_COMPLETED)";
    case 3: return "connected (WL_CONNECTED)";
    case 4: return "joining failed: wrong GF_WIFI_PASSWORD? (WL_CONNECT_FAILED)";
    case 5: return "the connection was lost (WL_CONNECTION_LOST)";
    case 6: return "not connected (WL_DISCONNECTED)";
    case 254: return "WiFi is stopped (WL_STOPPED)";
    case 255: return "no WiFi hardware (WL_NO_SHIELD)";
    default: return "WiFi status " + std::to_string(status);
  }
}

}  // namespace gf
