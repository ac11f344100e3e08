// Host build only: the sketch smoke test uses the example configuration.
#pragma once
#include "../../esp32_unit/config.example.h"
