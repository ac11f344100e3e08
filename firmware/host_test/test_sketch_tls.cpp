// The sketch's choice of network client: TLS trusting config.h's CA when one is given, plain TCP
// when GF_MQTT_CA_PEM is empty, and the example's placeholder refused.
#include <doctest/doctest.h>

#include <PubSubClient.h>
#include <WiFiClientSecure.h>
#include <config.h>

#include "../esp32_unit/src/pubsub_transport.h"
#include "../esp32_unit/src/tls_config.h"

extern PubSubClient mqttClient;
extern WiFiClient wifiClient;
extern WiFiClient& netClient;
extern gf::SecureClient secureClient;
extern gf::WatchedClient watchedClient;

TEST_CASE("with a CA in config.h the sketch talks MQTT through WiFiClientSecure trusting it") {
  CHECK(mqttClient.network == &watchedClient);
  CHECK(&netClient == &secureClient);
  CHECK(watchedClient.usesTls());
  CHECK(secureClient.caCert == GF_MQTT_CA_PEM);
  CHECK(secureClient.caCertCalls == 1);
  CHECK(std::string(kExampleBrokers) == "192.168.1.10:8883");  // the example: TLS's port
}

TEST_CASE("a TLS connection attempt is bounded: TCP connect and handshake timeouts are set") {
  // arduino-esp32 would otherwise wait 30 s for the TCP connect and 120 s for the handshake.
  CHECK(secureClient.handshakeTimeoutS == gf::kTlsHandshakeTimeoutS);
  REQUIRE(secureClient.connects > 0);
  CHECK(secureClient.lastTimeoutMs == static_cast<int32_t>(gf::kTcpConnectTimeoutMs));
  // To the broker of the list the device is on, the one PubSubClient was told too.
  CHECK(secureClient.lastHost == mqttClient.host);
  CHECK(secureClient.lastPort == mqttClient.port);
  CHECK(secureClient.lastPort == 8883);
  CHECK(gf::kConnectAttemptBoundMs <= 10000);
}

TEST_CASE("a buffer PubSubClient cannot allocate is a configuration problem, not ignored") {
  WiFiClient plain;
  PubSubClient client(plain);
  CHECK(gf::configureClient(client, gf::kMqttBufferBytes).empty());
  client.acceptBufferSize = false;
  CHECK(gf::configureClient(client, gf::kMqttBufferBytes).find("no memory") != std::string::npos);
}

TEST_CASE("an empty CA means plain TCP and no CA is set") {
  WiFiClient plain;
  WiFiClientSecure secure;
  CHECK(&gf::chooseClient(plain, secure, "") == &plain);
  CHECK(secure.caCertCalls == 0);
  CHECK(&gf::chooseClient(plain, secure, "-----BEGIN CERTIFICATE-----") == &secure);
  CHECK(secure.caCertCalls == 1);
}

TEST_CASE("the CA must be a PEM certificate, and not the example's placeholder") {
  CHECK(gf::caProblem("").empty());
  CHECK(gf::caProblem(GF_MQTT_CA_PEM).empty());
  CHECK(gf::caProblem(kExampleCaPem).find("placeholder") != std::string::npos);
  CHECK(gf::caProblem("MIIBdTCCARugAwIBAgIU").find("not a PEM certificate") != std::string::npos);
}
