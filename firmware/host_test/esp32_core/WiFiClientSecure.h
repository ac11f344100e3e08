// Host stand-in for arduino-esp32 2.x's WiFiClientSecure.h (3.x: NetworkClientSecure.h).
#pragma once
#include "secure_client.h"
#if ESP_ARDUINO_VERSION_MAJOR >= 3
typedef NetworkClientSecure WiFiClientSecure;
#endif
