// Topic names and the plain-text device payloads of protocol.md (direction, estop, connection).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

namespace gf {

enum class Direction : uint8_t { None, N, E, S, W };
enum class EstopKind : uint8_t { Invalid, Engaged, Released };

constexpr size_t kMaxEstopBytes = 512;  // protocol.md 5.1
constexpr size_t kMaxReasonChars = 200;

// An id: 1-64 of letters, digits, '_', '.', '-', starting with a letter or digit.
bool isValidId(const std::string& id);
// A topic root: '/'-separated segments of letters, digits, '_', '.', '-'.
bool isValidRoot(const std::string& root);

std::string directionTopic(const std::string& root, const std::string& unit);
std::string estopTopic(const std::string& root);
std::string deviceConnectionTopic(const std::string& root, const std::string& device);

// Exactly one of `N E S W -`; anything else returns false and leaves `out` alone.
bool parseDirection(const uint8_t* payload, size_t len, Direction& out);
// `engaged|<by>|<reason>` or `released|<by>|<reason>`, checked as strictly as the Python side.
EstopKind parseEstop(const uint8_t* payload, size_t len);
// What the button publishes: `engaged|<device>|button`.
std::string buttonEstopPayload(const std::string& device);

}  // namespace gf
