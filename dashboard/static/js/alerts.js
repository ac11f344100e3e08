// Alerts as the page shows them (protocol.md §5.8, §6.7): which stay on screen as notifications
// (every alert nobody has acknowledged yet, in force or cleared since), the Alerts view's rows,
// and the acknowledgement a button sends. Pure: no DOM, no network.

export const TOASTS_SHOWN = 4; // notifications on screen at once; the rest are counted
const SEVERITY_ORDER = { critical: 0, warning: 1 };

/** The alerts view's lists from `fleet/alerts` (parsed): {active, cleared}; malformed parts left out. */
export function alertsOf(msg) {
  const list = (v) => (Array.isArray(v) ? v.filter((a) => a && typeof a.id === "string" && typeof a.text === "string") : []);
  return { active: list(msg?.active), cleared: list(msg?.cleared) };
}

/**
 * The notifications: every alert without an acknowledgement, in force or cleared (a person must
 * still hear of a unit lost for a minute at night), critical first, then oldest first.
 */
export function unacknowledged(alerts) {
  return [...alerts.active, ...alerts.cleared]
    .filter((a) => !a.acked_by)
    .sort((a, b) => (SEVERITY_ORDER[a.severity] ?? 2) - (SEVERITY_ORDER[b.severity] ?? 2)
      || String(a.raised_at).localeCompare(String(b.raised_at)));
}

/** What a notification says under its text: when raised, and cleared if it is. */
export function alertWhen(a, clock) {
  const raised = `raised ${clock(a.raised_at)}`;
  return a.cleared_at ? `${raised} · cleared ${clock(a.cleared_at)}` : `${raised} · in force`;
}

/** "+ 3 more not acknowledged: see Alerts" under the notifications shown; "" when all show. */
export function moreText(count, shown = TOASTS_SHOWN) {
  return count > shown ? `+ ${count - shown} more not acknowledged: see Alerts` : "";
}

/** The ack_alert request of a notification's button. */
export function ackRequest(alert) {
  return { what: `acknowledge ${alert.rule ?? "alert"} ${alert.id}`, body: { alert_id: alert.id } };
}

/** The Alerts view's row of one alert: [text, className] each. */
export function alertCells(a, clock) {
  const acked = a.acked_by ? `${a.acked_by} ${clock(a.acked_at)}` : "not yet";
  return [
    [a.severity ?? "", "severity"], [a.text, "text"], [clock(a.raised_at), "at"],
    [a.cleared_at ? clock(a.cleared_at) : "in force", "cleared"], [acked, "acked"],
  ];
}

/** A key that changes whenever anything shown of the alerts does (to redraw only then). */
export function alertsKey(alerts) {
  return [...alerts.active, ...alerts.cleared].map((a) => `${a.id}:${a.cleared_at ?? ""}:${a.acked_by ?? ""}`).join(" ");
}
