// The page's broker connection: an MQTT.js client over websockets, its state in words, and the
// page's subscriptions, made again on every connect (a restarted broker has forgotten them). No DOM:
// the page hears the state through `onStatus`.
//
// A cluster's brokers come as a list (comma-separated): the page is on one at a time, and each
// attempt to connect after a loss goes to the next one of the list (MQTT.js's `transformWsUrl`
// names the URL of each attempt; its `servers` option cannot, as it keeps one path for all),
// quickly within a round of the list, every `reconnectPeriod` once a whole round has failed.

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

/** The pause (ms) before trying the next broker of a list while a round of it is not over. */
export const NEXT_BROKER_MS = 200;

/** The broker URLs of `spec`: a comma-separated list (one URL is a list of one), or an array. */
export function brokerUrls(spec) {
  const urls = (Array.isArray(spec) ? spec : String(spec ?? "").split(",")).map((u) => u.trim());
  if (!urls.length || urls.some((u) => !u)) throw new Error(`no broker URL in ${JSON.stringify(spec)}`);
  return urls;
}

/** A broker URL as the page names it: host and port (and path), without the scheme. */
export function brokerName(url) {
  return url.replace(/^[a-z]+:\/\//i, "").replace(/\/$/, "");
}

/**
 * Which broker of `urls` each attempt to connect goes to: the first, then the next after each
 * attempt (wrapping round). `pauseAfter()`: how long to wait after the current attempt fails,
 * short until every broker was tried since the last connection, then `roundMs`.
 */
export class BrokerRotation {
  constructor(urls, roundMs) {
    this.urls = urls;
    this.roundMs = roundMs;
    this.index = -1; // none tried yet
    this.tried = 0; // attempts since the last connection
  }

  /** The broker the page is on (or trying): its URL. */
  get where() { return this.urls[Math.max(this.index, 0)]; }

  /** The broker the next attempt goes to (its URL). */
  get upcoming() { return this.urls[(this.index + 1) % this.urls.length]; }

  /** The URL of the next attempt to connect. */
  next() {
    this.index = (this.index + 1) % this.urls.length;
    this.tried += 1;
    return this.where;
  }

  /** The attempt connected: a later loss starts a new round. */
  connected() { this.tried = 0; }

  pauseAfter() {
    return this.tried >= this.urls.length ? this.roundMs : Math.min(NEXT_BROKER_MS, this.roundMs);
  }
}

export class BrokerConnection {
  /**
   * `mqtt` is the MQTT.js module (its `connect`), `url` the broker's websocket URL or a list of
   * them (brokerUrls), `subs` the subscriptions ({topic: {qos}}).
   * Callbacks: `onStatus(state, text)` with state "connected", "reconnecting" or "failed" (with a
   * list, the text names the broker); `onMessage(topic, payload, retained)`; `onLog(text)` for
   * broker errors. `login` is {username, password} when the broker has accounts, else {}.
   */
  constructor(mqtt, url, clientId, subs, { onStatus, onMessage, onLog }, login = {}) {
    this.mqtt = mqtt;
    this.urls = brokerUrls(url);
    this.url = this.urls[0];
    this.clientId = clientId;
    this.subs = subs;
    this.onStatus = onStatus;
    this.onMessage = onMessage;
    this.onLog = onLog;
    this.login = login;
    this.state = "connecting"; // as the page says before the first status
    this.client = null;
    this.rotation = new BrokerRotation(this.urls, CLIENT_OPTIONS.reconnectPeriod);
  }

  /** The broker the page is on, or trying (its URL). */
  get where() { return this.rotation.where; }

  start() {
    const options = { clientId: this.clientId, ...CLIENT_OPTIONS, ...this.login };
    if (this.urls.length > 1) {
      // Called for each attempt's websocket (the first one too): it goes to the next broker.
      options.transformWsUrl = (_url, _options, client) => {
        const url = this.rotation.next();
        client.options.reconnectPeriod = this.rotation.pauseAfter();
        return url;
      };
    }
    const client = this.mqtt.connect(this.url, options);
    this.client = client;
    client.on("connect", () => {
      this.rotation.connected();
      if (this.urls.length > 1) client.options.reconnectPeriod = this.rotation.pauseAfter();
      client.subscribe(this.subs, (err) => {
        if (err) { this.status("failed", `subscribe failed: ${err.message}`); return; }
        this.status("connected", `broker: connected${this.naming("to")}`);
      });
    });
    // MQTT.js says "reconnect" just before the attempt: it goes to the upcoming broker.
    client.on("reconnect", () => this.status("reconnecting", `broker: reconnecting${this.naming("to", this.rotation.upcoming)}…`));
    client.on("close", () => { if (this.state === "connected") this.status("reconnecting", `broker${this.naming("")}: connection lost, reconnecting…`); });
    client.on("offline", () => this.status("reconnecting", "broker: offline, reconnecting…"));
    client.on("error", (err) => this.onLog(`broker error${this.naming("")}: ${err.message}`));
    client.on("message", (topic, payload, packet) => this.onMessage(topic, payload, !!packet?.retain));
    return this;
  }

  /** " to host:port" (`word` before the name of `url`, the current broker by default) with a
   * list of brokers; "" with one. */
  naming(word, url = this.where) {
    if (this.urls.length < 2) return "";
    return ` ${word ? `${word} ` : ""}${brokerName(url)}`;
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
