// Whether the page hears the fleet at all, and the broker badge's words. Pure: no DOM, no clock
// (callers pass `now` in milliseconds).
//
// A link that dies silently (no FIN: a laptop's Wi-Fi, a switch port) leaves the page "connected"
// until MQTT.js's keep-alive gives up on it (up to 1.5 × KEEP_ALIVE_S). The fleet tells it much
// sooner: while the page's link works, the coordinator's routes arrive every step (protocol.md
// §5.4) and each unit's state at least every 3 steps, so a page that hears nothing at all for many
// steps is deaf itself; its units are not all gone at once (model.js judges them against what the
// page last heard, as the coordinator does, protocol.md §8 "The coordinator's own silence").

// Ten steps without even the routes, each step's own message, cannot be one late message; and
// at least 3 s: a fleet at 0.1 s steps on a busy machine or browser (a garbage collection, the
// broker catching up) leaves gaps of a second or more that are nobody's lost link.
export const DEAF_STEPS = 10;
export const DEAF_FLOOR_MS = 3000;
const UNKNOWN_PERIOD_S = 1; // the course's step, until the coordinator's status says otherwise

/** The coordinator's step as the page should expect it (s): the longer of what it aims at and achieves. */
export function stepPeriodS(coordinator) {
  const periods = [coordinator?.step_period_s, coordinator?.achieved_step_s].filter((p) => Number.isFinite(p) && p > 0);
  return periods.length ? Math.max(...periods) : UNKNOWN_PERIOD_S;
}

/**
 * The step the page should hear news at (s), or null when none is due: only a coordinator whose
 * status says `online` sends its routes every step (one that is offline, broken or not yet heard
 * of leaves a working link quiet, and the badge says what its status says instead).
 */
export function newsPeriodS(coordinator) {
  return coordinator?.state === "online" ? stepPeriodS(coordinator) : null;
}

/** How long (ms) the page may hear nothing at all before it calls itself deaf. */
export function deafAfterMs(periodS) {
  return Math.max(DEAF_FLOOR_MS, DEAF_STEPS * periodS * 1000);
}

/**
 * The broker badge: the connection's own `state` and `text` ("connected", "reconnecting", …),
 * except that a connected page that has heard nothing since `since` (ms: the later of its last
 * message and its connecting) for longer than `deafAfterMs(periodS)` says so, as state "deaf";
 * `periodS` null (no news due: newsPeriodS) never does.
 */
export function brokerBadge(state, text, since, now, periodS) {
  if (state !== "connected" || since == null || periodS == null) return { state, text };
  const quiet = now - since;
  if (quiet <= deafAfterMs(periodS)) return { state, text };
  return {
    state: "deaf",
    text: `broker: nothing heard for ${Math.floor(quiet / 1000)} s — this page's link may be down`,
  };
}
