#include "protocol.h"

#include <cstring>

namespace gf {
namespace {

bool alnum(char c) {
  return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9');
}

bool idChar(char c) {
  return alnum(c) || (c != '\0' && std::strchr(proto::kIdPunctuation, c) != nullptr);
}

std::string topicPrefix(const std::string& root) {
  return root + "/" + proto::kTopicVersion + "/";
}

// True when `text` starts with `<word>|`; `pos` is then just past the separator.
bool startsWithWord(const std::string& text, const char* word, size_t& pos) {
  const size_t n = std::strlen(word);
  if (text.size() <= n || text.compare(0, n, word) != 0 || text[n] != proto::kEstopSeparator) {
    return false;
  }
  pos = n + 1;
  return true;
}

// Counts characters of valid UTF-8; returns false on any malformed sequence.
bool utf8Chars(const uint8_t* p, size_t len, size_t& chars) {
  chars = 0;
  size_t i = 0;
  while (i < len) {
    uint8_t b = p[i];
    size_t extra = 0;
    uint32_t cp = 0;
    if (b < 0x80) {
      extra = 0;
      cp = b;
    } else if ((b & 0xE0) == 0xC0) {
      extra = 1;
      cp = b & 0x1F;
    } else if ((b & 0xF0) == 0xE0) {
      extra = 2;
      cp = b & 0x0F;
    } else if ((b & 0xF8) == 0xF0) {
      extra = 3;
      cp = b & 0x07;
    } else {
      return false;
    }
    if (i + extra >= len && extra > 0) return false;  // truncated sequence
    for (size_t k = 1; k <= extra; ++k) {
      if ((p[i + k] & 0xC0) != 0x80) return false;
      cp = (cp << 6) | (p[i + k] & 0x3F);
    }
    // Overlong forms and surrogates are not valid UTF-8 (Python refuses them too).
    static const uint32_t kMin[4] = {0, 0x80, 0x800, 0x10000};
    if (cp < kMin[extra] || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return false;
    i += extra + 1;
    ++chars;
  }
  return true;
}

}  // namespace

bool isValidId(const std::string& id) {
  if (id.empty() || id.size() > proto::kMaxIdChars || !alnum(id[0])) return false;
  for (char c : id) {
    if (!idChar(c)) return false;
  }
  return true;
}

bool isValidRoot(const std::string& root) {
  if (root.size() > kMaxRootBytes) return false;
  size_t start = 0;
  while (true) {
    size_t slash = root.find('/', start);
    size_t end = slash == std::string::npos ? root.size() : slash;
    size_t n = end - start;
    if (n == 0 || n > proto::kMaxIdChars) return false;
    for (size_t i = start; i < end; ++i) {
      if (!idChar(root[i])) return false;
    }
    if (slash == std::string::npos) return true;
    start = slash + 1;
  }
}

std::string directionTopic(const std::string& root, const std::string& unit) {
  return topicPrefix(root) + proto::kTopicDirectionBefore + unit + proto::kTopicDirectionAfter;
}

std::string estopTopic(const std::string& root) { return topicPrefix(root) + proto::kTopicEstop; }

std::string deviceConnectionTopic(const std::string& root, const std::string& device) {
  return topicPrefix(root) + proto::kTopicDeviceConnectionBefore + device +
         proto::kTopicDeviceConnectionAfter;
}

std::string deviceStopTopic(const std::string& root, const std::string& device) {
  return topicPrefix(root) + proto::kTopicDeviceStopBefore + device + proto::kTopicDeviceStopAfter;
}

bool parseDirection(const uint8_t* payload, size_t len, Direction& out) {
  if (payload == nullptr || len != 1) return false;
  switch (payload[0]) {
    case proto::kDirectionN: out = Direction::N; return true;
    case proto::kDirectionE: out = Direction::E; return true;
    case proto::kDirectionS: out = Direction::S; return true;
    case proto::kDirectionW: out = Direction::W; return true;
    case proto::kDirectionNone: out = Direction::None; return true;
    default: return false;
  }
}

EstopKind parseEstop(const uint8_t* payload, size_t len) {
  if (payload == nullptr || len > kMaxEstopBytes) return EstopKind::Invalid;
  const std::string text(reinterpret_cast<const char*>(payload), len);
  EstopKind kind;
  size_t pos = 0;
  if (startsWithWord(text, proto::kEstopEngaged, pos)) {
    kind = EstopKind::Engaged;
  } else if (startsWithWord(text, proto::kEstopReleased, pos)) {
    kind = EstopKind::Released;
  } else {
    return EstopKind::Invalid;
  }
  size_t bar = text.find(proto::kEstopSeparator, pos);
  std::string by = text.substr(pos, bar == std::string::npos ? std::string::npos : bar - pos);
  if (!isValidId(by)) return EstopKind::Invalid;
  if (bar == std::string::npos) return kind;
  const uint8_t* reason = payload + bar + 1;
  size_t reasonLen = len - bar - 1;
  for (size_t i = 0; i < reasonLen; ++i) {
    if (reason[i] == '\r' || reason[i] == '\n' || reason[i] == '\0') return EstopKind::Invalid;
  }
  size_t chars = 0;
  if (!utf8Chars(reason, reasonLen, chars) || chars > kMaxReasonChars) return EstopKind::Invalid;
  return kind;
}

std::string buttonEstopPayload(const std::string& device) {
  return std::string(proto::kEstopEngaged) + proto::kEstopSeparator + device +
         proto::kEstopSeparator + kButtonReason;
}

}  // namespace gf
