// The page's broker connection: an MQTT.js client over websockets, its state in words, and the
// page's subscriptions, made again on every connect (a restarted broker has forgotten them). No DOM:
// the page hears the state through `onStatus`.

// The page's MQTT keep-alive (s), every gridfleet client's (gridfleet/bus.py KEEP_ALIVE_S): the
// broker ends the page's session 1.5 × it after its link dies, and MQTT.js gives up a connection
// whose ping goes unanswered as soon (then reconnects). The page knows sooner that it hears
// nothing (hearing.js).
export const KEEP_ALIVE_S = 10;

/** MQTT.js options besides the client id. */
export const CLIENT_OPTIONS = {
  clean: true,
  reconnectPeriod: 1000,
  connectTimeout: 5000,
  keepalive: KEEP_ALIVE_S,
  resubscribe: false, // we subscribe on every connect ourselves, so a restarted broker gets them
};

export class BrokerConnection {
  /**
   * `mqtt` is the MQTT.js module (its `connect`), `subs` the subscriptions ({topic: {qos}}).
   * Callbacks: `onStatus(state, text)` with state "connected", "reconnecting" or "failed";
   * `onMessage(topic, payload, retained)`; `onLog(text)` for broker errors. `login` is {username, password}
   * when the broker has accounts, else {}.
   */
  constructor(mqtt, url, clientId, subs, { onStatus, onMessage, onLog }, login = {}) {
    this.mqtt = mqtt;
    this.url = url;
    this.clientId = clientId;
    this.subs = subs;
    this.onStatus = onStatus;
    this.onMessage = onMessage;
    this.onLog = onLog;
    this.login = login;
    this.state = "connecting"; // as the page says before the first status
    this.client = null;
  }

  start() {
    const client = this.mqtt.connect(this.url, { clientId: this.clientId, ...CLIENT_OPTIONS, ...this.login });
    this.client = client;
    client.on("connect", () => {
      client.subscribe(this.subs, (err) => {
        if (err) { this.status("failed", `subscribe failed: ${err.message}`); return; }
        this.status("connected", "broker: connected");
      });
    });
    client.on("reconnect", () => this.status("reconnecting", "broker: reconnecting…"));
    client.on("close", () => { if (this.state === "connected") this.status("reconnecting", "broker: connection lost, reconnecting…"); });
    client.on("offline", () => this.status("reconnecting", "broker: offline, reconnecting…"));
    client.on("error", (err) => this.onLog(`broker error: ${err.message}`));
    client.on("message", (topic, payload, packet) => this.onMessage(topic, payload, !!packet?.retain));
    return this;
  }

  /** Close the connection for good (logging out); resolves once it is closed. */
  stop() {
    return new Promise((done) => {
      if (!this.client) { done(); return; }
      this.client.end(true, {}, () => done());
    });
  }

  status(state, text) {
    this.state = state;
    this.onStatus(state, text);
  }

  /** True while the client has a live connection (else MQTT.js queues what is published). */
  get connected() { return !!this.client?.connected; }

  publish(topic, payload, options) {
    this.client.publish(topic, payload, options);
  }
}
