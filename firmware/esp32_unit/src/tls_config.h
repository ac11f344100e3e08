// Whether the device encrypts its broker connection: config.h's GF_MQTT_CA_PEM, the CA that
// signed the broker's certificate (`gridfleet accounts tls` writes it as ca.pem); empty: plain
// TCP MQTT. Header-only, so the sketch and the host tests share it.
#pragma once

#include <cstring>
#include <string>

namespace gf {

// Words of config.example.h's placeholder: a device must not try TLS with it.
constexpr const char* kCaPlaceholder = "paste the lines of ca.pem here";

// True when a CA is given: connect with TLS and verify the broker against it.
inline bool usesTls(const char* caPem) { return caPem != nullptr && caPem[0] != '\0'; }

// Why `caPem` cannot be the CA certificate; empty when it can be (or is empty: plain TCP).
inline std::string caProblem(const char* caPem) {
  if (!usesTls(caPem)) return "";
  if (std::strstr(caPem, kCaPlaceholder) != nullptr) {
    return "GF_MQTT_CA_PEM still holds the example's placeholder: paste ca.pem (from "
           "'gridfleet accounts tls'), or \"\" for plain TCP";
  }
  if (std::strstr(caPem, "-----BEGIN CERTIFICATE-----") == nullptr ||
      std::strstr(caPem, "-----END CERTIFICATE-----") == nullptr) {
    return "GF_MQTT_CA_PEM is not a PEM certificate (-----BEGIN CERTIFICATE----- ... "
           "-----END CERTIFICATE-----)";
  }
  return "";
}

// The network client PubSubClient should use: `secure`, trusting `caPem`, when a CA is given,
// else `plain`. Called once, before PubSubClient is built on the result.
template <typename Plain, typename Secure>
Plain& chooseClient(Plain& plain, Secure& secure, const char* caPem) {
  if (!usesTls(caPem)) return plain;
  secure.setCACert(caPem);  // keeps the pointer: caPem must outlive the client (a literal does)
  return secure;
}

}  // namespace gf
