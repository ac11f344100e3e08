// The parts of protocol.md the page needs: topic names, headers, estop text. No DOM, no network.
// The facts themselves (version, topics, QoS, payload words, limits) come from protocol_table.js,
// which `make schemas` generates from the Python protocol package.

import {
  ESTOP, FINAL_JOB_STATES as FINAL_STATES, IDS, PROTOCOL_VERSION, SUBSCRIBE_QOS, TOPIC_VERSION,
  TOPICS,
} from "./protocol_table.js";

export { PROTOCOL_VERSION };
export const ID_RE = new RegExp(IDS.pattern);
export const FINAL_JOB_STATES = new Set(FINAL_STATES);

const kindsWhere = (test) => Object.keys(TOPICS).filter((kind) => test(TOPICS[kind], kind));
const UNIT_KINDS = new Set(kindsWhere((t) => t.placeholder === "unit"));
// A device topic's last level -> its kind (devices/<device>/stop is `device_stop`).
const DEVICE_KINDS = new Map(
  kindsWhere((t) => t.placeholder === "device").map((k) => [TOPICS[k].pattern.split("/").pop(), k]),
);
const REQUEST_KINDS = new Set(kindsWhere((t) => t.pattern.startsWith("requests/")));
// Answers addressed to one client (replies/<client>, history/replies/<client>, …), by path.
const CLIENT_KINDS = new Map(
  kindsWhere((t) => t.placeholder === "client").map((k) => [TOPICS[k].pattern.replace("/{client}", ""), k]),
);
// Fleet-wide topics by path (fleet/..., errors, coordinator/status); the page reads no requests.
const FLEET_KINDS = new Map(
  kindsWhere((t, kind) => !t.placeholder && !REQUEST_KINDS.has(kind)).map((k) => [TOPICS[k].pattern, k]),
);

/** `kind`'s topic under `prefix`, its placeholder (unit, client, device) filled with `value`. */
function topicOf(prefix, kind, value) {
  const spec = TOPICS[kind];
  const path = spec.placeholder ? spec.pattern.replace(`{${spec.placeholder}}`, value) : spec.pattern;
  return `${prefix}/${path}`;
}

function check(kinds, kind, what) {
  if (!kinds.has(kind)) throw new Error(`${kind} is not ${what}`);
  return kind;
}

/** Topic names under `<root>/v1`. */
export function topicsFor(root) {
  const p = `${root}/${TOPIC_VERSION}`;
  return {
    prefix: p,
    estop: topicOf(p, "estop"),
    map: topicOf(p, "map"),
    jobs: topicOf(p, "jobs"),
    routes: topicOf(p, "routes"),
    events: topicOf(p, "events"),
    energy: topicOf(p, "energy"),
    zones: topicOf(p, "zones"),
    alerts: topicOf(p, "alerts"),
    errors: topicOf(p, "errors"),
    coordinator: topicOf(p, "coordinator"),
    revoke: topicOf(p, "revoke"), // the dashboard server's word to the broker; the page never reads it
    allUnits: (kind) => topicOf(p, check(UNIT_KINDS, kind, "a per-unit topic kind"), "+"),
    allDevices: (kind) => topicOf(p, check(new Set(DEVICE_KINDS.values()), kind, "a per-device topic kind"), "+"),
    request: (kind) => topicOf(p, check(REQUEST_KINDS, kind, "a request kind")),
    reply: (client) => topicOf(p, "reply", client),
    historyReply: (client) => topicOf(p, "history_reply", client),
    auditReply: (client) => topicOf(p, "audit_reply", client),
  };
}

// What the page reads: every unit's connection, factsheet, state and (a VDA 5050 vehicle's) own
// condition, the fleet views (the energy policy's and the closed zones too), its replies and the
// history's pages.
const SUBSCRIBED_UNIT_KINDS = ["connection", "factsheet", "state", "vehicle"];
const SUBSCRIBED_FLEET_KINDS = [
  "estop", "map", "jobs", "routes", "coordinator", "errors", "events", "alerts", "energy", "zones",
];

/**
 * What the page subscribes to, every topic at SUBSCRIBE_QOS (protocol.md §2: a clean session).
 * `audit`: this login may read the audit (protocol.md §6.8); the broker refuses the audit's
 * replies to any other account, so the page does not ask for them then.
 */
export function subscriptions(topics, clientId, { audit = true } = {}) {
  // The fleet's views (the latch, the map) before every unit's records: a broker replays the
  // retained messages of a SUBSCRIBE filter by filter, and Mosquitto drops a QoS 0 delivery once
  // a client has max_queued_messages (1000) packets waiting; 500 units' records come to 1,500.
  const filters = [
    ...SUBSCRIBED_FLEET_KINDS.map((kind) => topics[kind]),
    ...SUBSCRIBED_UNIT_KINDS.map((kind) => topics.allUnits(kind)),
    // Every stop press, so a press shows even before the coordinator copies it into the latch.
    topics.allUnits("stop"),
    topics.allDevices("device_stop"),
    topics.reply(clientId),
    topics.historyReply(clientId),
    ...(audit ? [topics.auditReply(clientId)] : []),
  ];
  return Object.fromEntries(filters.map((filter) => [filter, { qos: SUBSCRIBE_QOS }]));
}

/** Split a topic into {kind, id}; null for anything that is not ours. */
export function parseTopic(prefix, topic) {
  if (!topic.startsWith(prefix + "/")) return null;
  const rest = topic.slice(prefix.length + 1).split("/");
  if (rest.length === 3 && rest[0] === "units" && UNIT_KINDS.has(rest[2]) && ID_RE.test(rest[1])) {
    return { kind: rest[2], id: rest[1] };
  }
  if (rest.length === 3 && rest[0] === "devices" && DEVICE_KINDS.has(rest[2]) && ID_RE.test(rest[1])) {
    return { kind: DEVICE_KINDS.get(rest[2]), id: rest[1] };
  }
  const client = rest.pop();
  const answer = CLIENT_KINDS.get(rest.join("/"));
  if (answer && ID_RE.test(client)) return { kind: answer, id: client };
  rest.push(client);
  const kind = FLEET_KINDS.get(rest.join("/"));
  return kind ? { kind, id: null } : null;
}

/** Headers for one sender: a counter per topic kind and a UTC timestamp. */
export class Stamper {
  constructor(sender) {
    this.sender = sender;
    this.seq = new Map();
  }
  header(kind) {
    const seq = this.seq.get(kind) ?? 0;
    this.seq.set(kind, seq + 1);
    return { version: PROTOCOL_VERSION, seq, timestamp: new Date().toISOString(), sender: this.sender };
  }
}

/** `engaged|<by>|<reason>` or `released|<by>|<reason>`; the reason is one line, ≤ 200 chars. */
export function encodeEstop(engaged, by, reason) {
  const line = String(reason).replace(/[\r\n\0]/g, " ").slice(0, ESTOP.max_reason_chars);
  return [engaged ? ESTOP.engaged : ESTOP.released, by, line].join(ESTOP.separator);
}

/** Parse an estop payload; null when it is not valid (never treated as a release). */
export function decodeEstop(text) {
  const parts = text.split(ESTOP.separator);
  if (parts.length < 2 || (parts[0] !== ESTOP.engaged && parts[0] !== ESTOP.released)) return null;
  if (!ID_RE.test(parts[1])) return null;
  return { engaged: parts[0] === ESTOP.engaged, by: parts[1], reason: parts.slice(2).join(ESTOP.separator) };
}

/** A stop press of `source` (its own stop topic): {engaged, by, reason}; null when cleared (empty). */
export function decodePress(text, source) {
  if (text === "") return null;
  const signal = decodeEstop(text);
  if (!signal || !signal.engaged || signal.by !== source) throw new Error(`not a stop press of ${source}`);
  return signal;
}

/** A client id for this page: prefix plus random hex, always a valid protocol id. */
export function makeClientId(prefix) {
  const bytes = new Uint8Array(4);
  crypto.getRandomValues(bytes);
  const hex = Array.from(bytes, (b) => b.toString(16).padStart(2, "0")).join("");
  return `${prefix}-${hex}`.slice(0, 64);
}
