// The parts of protocol.md the page needs: topic names, headers, estop text. No DOM, no network.

export const PROTOCOL_VERSION = "1.0";
export const ID_RE = /^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$/;
export const FINAL_JOB_STATES = new Set(["done", "cancelled", "rejected", "failed"]);

/** Topic names under `<root>/v1`. */
export function topicsFor(root) {
  const p = `${root}/v1`;
  return {
    prefix: p,
    estop: `${p}/fleet/estop`,
    map: `${p}/fleet/map`,
    jobs: `${p}/fleet/jobs`,
    routes: `${p}/fleet/routes`,
    errors: `${p}/errors`,
    coordinator: `${p}/coordinator/status`,
    allUnits: (kind) => `${p}/units/+/${kind}`,
    request: (kind) => `${p}/requests/${kind}`,
    reply: (client) => `${p}/replies/${client}`,
  };
}

/** What the page subscribes to, with the QoS protocol.md asks for (high-rate topics at 0). */
export function subscriptions(topics, clientId) {
  return {
    [topics.allUnits("connection")]: { qos: 1 },
    [topics.allUnits("factsheet")]: { qos: 1 },
    [topics.allUnits("state")]: { qos: 0 },
    [topics.estop]: { qos: 1 },
    [topics.map]: { qos: 1 },
    [topics.jobs]: { qos: 1 },
    [topics.routes]: { qos: 0 },
    [topics.coordinator]: { qos: 1 },
    [topics.errors]: { qos: 1 },
    [topics.reply(clientId)]: { qos: 1 },
  };
}

const FLEET_KINDS = {
  "fleet/estop": "estop", "fleet/map": "map", "fleet/jobs": "jobs", "fleet/routes": "routes",
  "errors": "errors", "coordinator/status": "coordinator",
};
const UNIT_KINDS = new Set(["connection", "factsheet", "state", "order", "goal", "direction"]);

/** Split a topic into {kind, id}; null for anything that is not ours. */
export function parseTopic(prefix, topic) {
  if (!topic.startsWith(prefix + "/")) return null;
  const rest = topic.slice(prefix.length + 1).split("/");
  if (rest.length === 3 && rest[0] === "units" && UNIT_KINDS.has(rest[2]) && ID_RE.test(rest[1])) {
    return { kind: rest[2], id: rest[1] };
  }
  if (rest.length === 2 && rest[0] === "replies" && ID_RE.test(rest[1])) {
    return { kind: "reply", id: rest[1] };
  }
  const kind = FLEET_KINDS[rest.join("/")];
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
  const line = String(reason).replace(/[\r\n\0]/g, " ").slice(0, 200);
  return `${engaged ? "engaged" : "released"}|${by}|${line}`;
}

/** Parse an estop payload; null when it is not valid (never treated as a release). */
export function decodeEstop(text) {
  const parts = text.split("|");
  if (parts.length < 2 || (parts[0] !== "engaged" && parts[0] !== "released")) return null;
  if (!ID_RE.test(parts[1])) return null;
  return { engaged: parts[0] === "engaged", by: parts[1], reason: parts.slice(2).join("|") };
}

/** A client id for this page: prefix plus random hex, always a valid protocol id. */
export function makeClientId(prefix) {
  const bytes = new Uint8Array(4);
  crypto.getRandomValues(bytes);
  const hex = Array.from(bytes, (b) => b.toString(16).padStart(2, "0")).join("");
  return `${prefix}-${hex}`.slice(0, 64);
}
