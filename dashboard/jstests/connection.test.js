// The broker connection with a stand-in for MQTT.js: options, status words, subscribing on every connect.
import assert from "node:assert/strict";
import { EventEmitter } from "node:events";
import { test } from "node:test";
import {
  BrokerConnection, BrokerRotation, CLIENT_OPTIONS, NEXT_BROKER_MS, brokerName, brokerUrls,
} from "../static/js/connection.js";

/** What MQTT.js's `connect` returns, as far as the page uses it. */
class FakeClient extends EventEmitter {
  constructor(url, options) {
    super();
    Object.assign(this, { url, options, connected: false, subscribed: [], published: [], subscribeError: null });
  }
  subscribe(subs, cb) { this.subscribed.push(subs); cb(this.subscribeError); }
  publish(topic, payload, options) { this.published.push({ topic, payload, options }); }
}

function open(login = undefined, url = "ws://broker:9001") {
  const calls = { status: [], messages: [], log: [] };
  let client = null;
  const mqtt = { connect: (url, options) => (client = new FakeClient(url, options)) };
  const subs = { "lab/v1/fleet/estop": { qos: 1 } };
  const conn = new BrokerConnection(mqtt, url, "dash-1", subs, {
    onStatus: (state, text) => calls.status.push([state, text]),
    onMessage: (topic, payload) => calls.messages.push([topic, payload]),
    onLog: (text) => calls.log.push(text),
  }, login).start();
  return { conn, client, calls, subs };
}

test("the client is clean, reconnects every second, and leaves resubscribing to us", () => {
  const { client, conn } = open();
  assert.equal(client.url, "ws://broker:9001");
  assert.deepEqual(client.options, { clientId: "dash-1", ...CLIENT_OPTIONS });
  assert.equal(client.options.clean, true);
  assert.equal(client.options.resubscribe, false);
  assert.equal(client.options.reconnectPeriod, 1000);
  assert.equal(conn.state, "connecting");
});

test("connected only once subscribed; subscribed again on every connect", () => {
  const { client, calls, subs } = open();
  client.emit("connect");
  assert.deepEqual(client.subscribed, [subs]);
  assert.deepEqual(calls.status, [["connected", "broker: connected"]]);
  client.emit("close");
  client.emit("offline");
  client.emit("reconnect");
  client.emit("connect"); // a restarted broker knows nothing of us
  assert.deepEqual(client.subscribed, [subs, subs]);
  assert.deepEqual(calls.status, [
    ["connected", "broker: connected"],
    ["reconnecting", "broker: connection lost, reconnecting…"],
    ["reconnecting", "broker: offline, reconnecting…"],
    ["reconnecting", "broker: reconnecting…"],
    ["connected", "broker: connected"],
  ]);
});

test("a close says 'connection lost' only when we were connected", () => {
  const { client, calls, conn } = open();
  client.emit("close");
  assert.deepEqual(calls.status, []);
  client.emit("reconnect");
  client.emit("close");
  assert.deepEqual(calls.status, [["reconnecting", "broker: reconnecting…"]]);
  assert.equal(conn.state, "reconnecting");
});

test("a refused subscription is a failure, in words", () => {
  const { client, calls, conn } = open();
  client.subscribeError = new Error("not authorised");
  client.emit("connect");
  assert.deepEqual(calls.status, [["failed", "subscribe failed: not authorised"]]);
  assert.equal(conn.state, "failed");
  client.emit("close");
  assert.equal(calls.status.length, 1, "no 'connection lost' after a failure");
});

test("messages and errors are passed on; publish goes to the client", () => {
  const { client, calls, conn } = open();
  const payload = new TextEncoder().encode("engaged|x|y");
  client.emit("message", "lab/v1/fleet/estop", payload);
  client.emit("error", new Error("boom"));
  assert.deepEqual(calls.messages, [["lab/v1/fleet/estop", payload]]);
  assert.deepEqual(calls.log, ["broker error: boom"]);
  assert.equal(conn.connected, false);
  client.connected = true;
  assert.equal(conn.connected, true);
  conn.publish("t", "p", { qos: 1, retain: true });
  assert.deepEqual(client.published, [{ topic: "t", payload: "p", options: { qos: 1, retain: true } }]);
});

test("with an account the client logs in with it; stop ends the client", async () => {
  const { client, conn } = open({ username: "operator", password: "pw" });
  assert.deepEqual(client.options, {
    clientId: "dash-1", ...CLIENT_OPTIONS, username: "operator", password: "pw",
  });
  let ended = null;
  client.end = (force, options, cb) => { ended = force; cb(); };
  await conn.stop();
  assert.equal(ended, true);
});

// ---- a list of brokers (a cluster's) ----

const LIST = "ws://a:9001, wss://b.lan:443/mqtt,ws://[fd00::5]:9001/";

/** One attempt to connect, as MQTT.js makes it: it asks transformWsUrl for its websocket's URL. */
function attempt(client) {
  return client.options.transformWsUrl("ws://what-mqtt-built:80/", client.options, client);
}

test("a list is split at its commas; an empty item or none is refused", () => {
  assert.deepEqual(brokerUrls("ws://h:9001"), ["ws://h:9001"]);
  assert.deepEqual(brokerUrls(LIST), ["ws://a:9001", "wss://b.lan:443/mqtt", "ws://[fd00::5]:9001/"]);
  assert.deepEqual(brokerUrls(["ws://a:1", " ws://b:2 "]), ["ws://a:1", "ws://b:2"]);
  assert.throws(() => brokerUrls("ws://a:1,,ws://b:2"), /no broker URL/);
  assert.throws(() => brokerUrls(""), /no broker URL/);
  assert.throws(() => brokerUrls([]), /no broker URL/);
  assert.equal(brokerName("wss://b.lan:443/mqtt"), "b.lan:443/mqtt");
  assert.equal(brokerName("ws://[fd00::5]:9001/"), "[fd00::5]:9001");
});

test("one broker: MQTT.js connects to it as given, with no rotation", () => {
  const { client, conn, calls } = open(undefined, "ws://solo:9001");
  assert.equal(client.url, "ws://solo:9001");
  assert.equal(client.options.transformWsUrl, undefined);
  client.emit("connect");
  assert.deepEqual(calls.status, [["connected", "broker: connected"]]);
  assert.equal(conn.where, "ws://solo:9001");
});

test("each attempt goes to the next broker of the list, whole URLs, round and round", () => {
  const { client } = open(undefined, LIST);
  assert.equal(client.url, "ws://a:9001");
  const urls = [attempt(client), attempt(client), attempt(client), attempt(client)];
  assert.deepEqual(urls, ["ws://a:9001", "wss://b.lan:443/mqtt", "ws://[fd00::5]:9001/", "ws://a:9001"]);
});

test("the next broker is tried quickly; after a whole round has failed, every second", () => {
  const { client } = open(undefined, LIST);
  const pauses = [];
  for (let i = 0; i < 5; i++) { attempt(client); pauses.push(client.options.reconnectPeriod); }
  const round = CLIENT_OPTIONS.reconnectPeriod;
  assert.deepEqual(pauses, [NEXT_BROKER_MS, NEXT_BROKER_MS, round, round, round]);
  assert.ok(NEXT_BROKER_MS < round);
  // Connected (to the fifth attempt's broker, b): when it dies, the next one is tried at once.
  client.emit("connect");
  assert.equal(client.options.reconnectPeriod, NEXT_BROKER_MS);
  assert.equal(attempt(client), "ws://[fd00::5]:9001/");
  assert.equal(client.options.reconnectPeriod, NEXT_BROKER_MS);
});

test("with a list the badge's words name the broker the page is on, and the one it tries", () => {
  const { client, calls, conn } = open(undefined, LIST);
  attempt(client);
  client.emit("connect");
  assert.equal(conn.where, "ws://a:9001");
  client.emit("close"); // a dies
  client.emit("reconnect");
  attempt(client);
  client.emit("error", new Error("refused"));
  client.emit("connect");
  assert.equal(conn.where, "wss://b.lan:443/mqtt");
  assert.deepEqual(calls.status, [
    ["connected", "broker: connected to a:9001"],
    ["reconnecting", "broker a:9001: connection lost, reconnecting…"],
    ["reconnecting", "broker: reconnecting to b.lan:443/mqtt…"],
    ["connected", "broker: connected to b.lan:443/mqtt"],
  ]);
  assert.deepEqual(calls.log, ["broker error b.lan:443/mqtt: refused"]);
});

test("the rotation alone: where it is, where it goes next", () => {
  const rotation = new BrokerRotation(["ws://a:1", "ws://b:2"], 1000);
  assert.equal(rotation.where, "ws://a:1");
  assert.equal(rotation.upcoming, "ws://a:1");
  assert.equal(rotation.next(), "ws://a:1");
  assert.equal(rotation.upcoming, "ws://b:2");
  assert.equal(rotation.pauseAfter(), NEXT_BROKER_MS);
  assert.equal(rotation.next(), "ws://b:2");
  assert.equal(rotation.pauseAfter(), 1000);
  rotation.connected();
  assert.equal(rotation.pauseAfter(), NEXT_BROKER_MS);
  assert.equal(rotation.where, "ws://b:2");
});
