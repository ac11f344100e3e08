// Host stand-in for arduino-esp32 3.x's NetworkClientSecure.h.
#pragma once
#include "secure_client.h"
