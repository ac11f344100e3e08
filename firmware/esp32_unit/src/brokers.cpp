#include "brokers.h"

#include <cstdlib>

namespace gf {

namespace {

std::string trimmed(const std::string& s) {
  size_t begin = 0;
  size_t end = s.size();
  while (begin < end && (s[begin] == ' ' || s[begin] == '\t')) ++begin;
  while (end > begin && (s[end - 1] == ' ' || s[end - 1] == '\t')) --end;
  return s.substr(begin, end - begin);
}

bool sameHost(const std::string& a, const std::string& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i) {
    const char x = (a[i] >= 'A' && a[i] <= 'Z') ? static_cast<char>(a[i] - 'A' + 'a') : a[i];
    const char y = (b[i] >= 'A' && b[i] <= 'Z') ? static_cast<char>(b[i] - 'A' + 'a') : b[i];
    if (x != y) return false;
  }
  return true;
}

bool isHostChar(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' ||
         c == '-';
}

// One item of the list: empty when usable (into `out`), else what is wrong with it.
std::string parseBroker(const std::string& item, bool tls, Broker& out) {
  std::string rest = item;
  const size_t scheme = rest.find("://");
  if (scheme != std::string::npos) {
    const std::string name = rest.substr(0, scheme);
    if (name == "mqtts" && !tls) {
      return "TLS (mqtts://) needs the broker's CA in GF_MQTT_CA_PEM";
    }
    if (name == "mqtt" && tls) {
      return "plain TCP (mqtt://), but GF_MQTT_CA_PEM asks for TLS to every broker: give "
             "mqtts:// or host:port";
    }
    if (name == "ws" || name == "wss") {
      return "the device speaks MQTT over TCP or TLS (mqtt://, mqtts://), not over websockets";
    }
    if (name != "mqtt" && name != "mqtts") return "unknown scheme '" + name + "://'";
    rest = rest.substr(scheme + 3);
  }
  if (rest.find('@') != std::string::npos) {
    return "no login here: the account goes in GF_MQTT_USER and GF_MQTT_PASSWORD";
  }
  if (rest.find('/') != std::string::npos || rest.find('?') != std::string::npos) {
    return "host:port only, no path";
  }
  const size_t colon = rest.find(':');
  const std::string host = rest.substr(0, colon);
  if (host.empty()) return "no host";
  for (char c : host) {
    if (!isHostChar(c)) return "'" + host + "' is not a host name or IPv4 address";
  }
  uint16_t port = tls ? kMqttTlsPort : kMqttPort;
  if (colon != std::string::npos) {
    const std::string digits = rest.substr(colon + 1);
    if (digits.empty() || digits.size() > 5 ||
        digits.find_first_not_of("0123456789") != std::string::npos) {
      return "port '" + digits + "' is not a number";
    }
    const long value = std::strtol(digits.c_str(), nullptr, 10);
    if (value < 1 || value > 65535) return "port " + digits + " is not 1-65535";
    port = static_cast<uint16_t>(value);
  }
  out.host = host;
  out.port = port;
  return "";
}

}  // namespace

std::string parseBrokers(const std::string& text, bool tls, std::vector<Broker>& out) {
  out.clear();
  std::vector<Broker> brokers;
  size_t start = 0;
  while (true) {
    const size_t comma = text.find(',', start);
    const std::string item =
        trimmed(text.substr(start, comma == std::string::npos ? std::string::npos : comma - start));
    if (item.empty()) {
      return "GF_MQTT_BROKERS \"" + text + "\": " +
             (trimmed(text).empty() ? std::string("no broker")
                                    : std::string("an empty item (two commas, or one at an end)"));
    }
    Broker broker;
    const std::string problem = parseBroker(item, tls, broker);
    if (!problem.empty()) return "GF_MQTT_BROKERS item '" + item + "': " + problem;
    for (const Broker& seen : brokers) {
      if (sameHost(seen.host, broker.host) && seen.port == broker.port) {
        return "GF_MQTT_BROKERS \"" + text + "\": " + broker.name() + " is in it twice";
      }
    }
    brokers.push_back(broker);
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  out = brokers;
  return "";
}

std::string brokerNames(const std::vector<Broker>& brokers) {
  std::string names;
  for (const Broker& broker : brokers) names += (names.empty() ? "" : ", ") + broker.name();
  return names;
}

bool BrokerRotation::failed() {
  index_ = (index_ + 1) % count_;
  if (++failures_ < count_) return true;
  failures_ = 0;
  return false;
}

void BrokerRotation::lost() {
  index_ = (index_ + 1) % count_;
  failures_ = 0;
}

}  // namespace gf
