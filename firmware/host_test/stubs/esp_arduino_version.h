// Host-only stand-in: the stand-in headers here have arduino-esp32 2.x's layout.
#pragma once
#define ESP_ARDUINO_VERSION_MAJOR 2
