// Host stand-in for arduino-esp32's esp_arduino_version.h: which core's layout the stand-in
// headers take (make builds the sketch with both: -DGF_HOST_ESP32_MAJOR=2 and 3).
#pragma once

#ifndef GF_HOST_ESP32_MAJOR
#define GF_HOST_ESP32_MAJOR 3
#endif
#define ESP_ARDUINO_VERSION_MAJOR GF_HOST_ESP32_MAJOR
#define ESP_ARDUINO_VERSION_MINOR 0
#define ESP_ARDUINO_VERSION_PATCH 0
