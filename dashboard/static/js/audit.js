// The Audit view's words (protocol.md §6.8): the query its filters make and each entry's cells.
// Pure: no DOM, no network, no clock.

import { DAY_MS, readTime } from "./history.js";
import { ID_RE } from "./protocol.js";

export const AUDIT_PAGE = 200; // entries a page asks for (the coordinator gives at most 500)

/**
 * Whether this login may read the audit: `audit` from the dashboard's settings (operator and
 * dashboard accounts; anybody without accounts, as the coordinator then allows). Settings from a
 * dashboard that does not say are read as allowed: the coordinator still refuses in words.
 */
export function mayReadAudit(settings) {
  return settings?.audit !== false;
}

/** The audit request the filters make ({since, until, actor}: the fields' text): {body} or {error}. */
export function auditQuery(fields, now, limit = AUDIT_PAGE) {
  let since, until;
  try {
    since = readTime(fields.since, "since") ?? new Date(now - DAY_MS);
    until = readTime(fields.until, "until");
  } catch (e) {
    return { error: e.message };
  }
  if (until && since >= until) return { error: `since ${fields.since} is not before until ${fields.until}` };
  const actor = (fields.actor ?? "").trim() || null;
  if (actor && !ID_RE.test(actor)) return { error: `account "${actor}": letters, digits, _ . - only (max 64)` };
  return { body: { since: since.toISOString(), until: until ? until.toISOString() : null, actor, limit, cursor: null } };
}

/** One entry's cells: [text, className] each. An account nobody vouched for ends in "?". */
export function auditCells(e, clock) {
  const actor = `${e.actor ?? "?"}${e.verified ? "" : "?"}`;
  const outcome = e.outcome === "refused" ? `refused: ${e.reason ?? "no reason given"}` : (e.outcome ?? "");
  return [
    [clock(e.at), "at"], [actor, "actor"], [e.act ?? "", "act"], [e.target ?? "—", "target"],
    [e.detail ?? "", "detail"], [outcome, e.outcome === "refused" ? "outcome refused" : "outcome"],
  ];
}
