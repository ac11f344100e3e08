// The sketch's adapters on the real PubSubClient 2.8 and ArduinoCore-API, over real sockets.
#include <doctest/doctest.h>

#include <Arduino.h>
#include <PubSubClient.h>
#include <WiFi.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <string>

#include "../../esp32_unit/src/pubsub_transport.h"

namespace {
// A loopback port nobody listens on.
uint16_t closedPort() {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof addr;
  REQUIRE(bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0);
  REQUIRE(getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len) == 0);
  close(fd);
  return ntohs(addr.sin_port);
}
}  // namespace

TEST_CASE("PubSubClient's buffer is checked: a size it cannot take is a configuration problem") {
  WiFiClient net;
  PubSubClient client(net);
  CHECK(gf::configureClient(client, gf::kMqttBufferBytes).empty());
  CHECK(client.getBufferSize() == gf::kMqttBufferBytes);
  CHECK(gf::configureClient(client, 0).find("no memory") != std::string::npos);
}

TEST_CASE("a broker that is not there: connect() fails at once and says why in words") {
  WiFiClient net;
  gf::WatchedClient watched(net, nullptr, gf::kMqttBufferBytes);
  PubSubClient client(watched);
  REQUIRE(gf::configureClient(client, gf::kMqttBufferBytes).empty());
  const uint16_t port = closedPort();
  gf::PubSubTransport transport(client, watched, "", "");
  transport.setBroker(gf::Broker("127.0.0.1", port));
  const unsigned long start = millis();
  CHECK_FALSE(transport.connect("dev1", "t/v1/devices/dev1/connection", "broken"));
  CHECK(millis() - start < 1000);
  const std::string why = transport.lastError();
  CHECK(why.find("no TCP connection to 127.0.0.1:" + std::to_string(port)) != std::string::npos);
  CHECK_FALSE(transport.connected());
}

TEST_CASE("the TLS client's timeouts bound an attempt against a broker that never answers") {
  // A listening socket nobody accepts from: TCP connects, the TLS handshake gets no answer.
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof addr;
  REQUIRE(bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0);
  REQUIRE(listen(fd, 4) == 0);
  REQUIRE(getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len) == 0);
  gf::SecureClient tls;
  tls.setHandshakeTimeout(1);  // seconds, as arduino-esp32 takes it
  gf::WatchedClient watched(tls, &tls, gf::kMqttBufferBytes);
  PubSubClient client(watched);
  gf::PubSubTransport transport(client, watched, "", "");
  transport.setBroker(gf::Broker("127.0.0.1", ntohs(addr.sin_port)));
  const unsigned long start = millis();
  CHECK_FALSE(transport.connect("dev1", "t/v1/devices/dev1/connection", "broken"));
  const unsigned long took = millis() - start;
  CHECK(took >= 900);
  CHECK(took < 2500);
  CHECK(transport.lastError().find("no TLS connection") != std::string::npos);
  CHECK(transport.lastError().find("timed out") != std::string::npos);
  close(fd);
}
