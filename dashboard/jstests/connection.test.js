// The broker connection with a stand-in for MQTT.js: options, status words, subscribing on every connect.
import assert from "node:assert/strict";
import { EventEmitter } from "node:events";
import { test } from "node:test";
import { BrokerConnection, CLIENT_OPTIONS } from "../static/js/connection.js";

/** What MQTT.js's `connect` returns, as far as the page uses it. */
class FakeClient extends EventEmitter {
  constructor(url, options) {
    super();
    Object.assign(this, { url, options, connected: false, subscribed: [], published: [], subscribeError: null });
  }
  subscribe(subs, cb) { this.subscribed.push(subs); cb(this.subscribeError); }
  publish(topic, payload, options) { this.published.push({ topic, payload, options }); }
}

function open(login = undefined) {
  const calls = { status: [], messages: [], log: [] };
  let client = null;
  const mqtt = { connect: (url, options) => (client = new FakeClient(url, options)) };
  const subs = { "lab/v1/fleet/estop": { qos: 1 } };
  const conn = new BrokerConnection(mqtt, "ws://broker:9001", "dash-1", subs, {
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
