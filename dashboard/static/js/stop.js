// The emergency stop on the page: one click on STOP engages it; releasing needs a deliberate
// press-and-hold. The payloads and how the stop looks are pure functions; the rest binds and shows.

import { encodeEstop } from "./protocol.js";

export const HOLD_MS = 1500; // release needs a deliberate press-and-hold

/**
 * The retained fleet/estop payload for STOP pressed (engaged) or the stop released on page
 * `clientId`. The latch names the page's own client id, which its account owns: a broker with
 * accounts drops a latch naming an id the publishing account does not own (protocol.md §10), so
 * a fixed name would make STOP on the page of any account but `dashboard` do nothing.
 */
export function estopPayload(engaged, clientId) {
  return encodeEstop(engaged, clientId, engaged ? "STOP pressed on the page" : "released on the page");
}

/**
 * How the page shows the stop, from the broker's `estop` ({engaged, by, reason} or null when nobody
 * has said) and `localStop` (STOP pressed here, not yet heard back from the broker):
 * {state: the body's data-estop, banner: its text or null (hidden), stopLabel, canRelease}.
 */
export function estopLook(estop, localStop) {
  const engaged = !!estop?.engaged;
  const stopped = engaged || localStop;
  let banner = null;
  if (stopped) {
    const why = engaged ? `${estop.by}${estop.reason ? ": " + estop.reason : ""}` : "";
    banner = !engaged
      ? "EMERGENCY STOP — sending…"
      : estop.press
        ? `EMERGENCY STOP — pressed on ${why} (not latched yet: is the coordinator running?)`
        : `EMERGENCY STOP — engaged by ${why}`;
  }
  return {
    state: stopped ? "engaged" : (estop ? "released" : "unknown"),
    banner,
    stopLabel: stopped ? "STOPPED" : "STOP",
    // Only a latched stop can be released: a press alone waits for the coordinator to latch it.
    canRelease: engaged && !estop.press,
  };
}

export function showEstop(look) {
  document.body.dataset.estop = look.state;
  const banner = document.querySelector("#estop-banner");
  banner.hidden = look.banner === null;
  if (look.banner !== null) banner.textContent = look.banner;
  document.querySelector("#stop").textContent = look.stopLabel;
  document.querySelector("#release").hidden = !look.canRelease;
}

/** `onStop()` on a click on STOP; `onRelease()` once "hold to release" has been held HOLD_MS. */
export function bindStopControls({ onStop, onRelease }) {
  document.querySelector("#stop").addEventListener("click", onStop);
  bindHold(document.querySelector("#release"), HOLD_MS, onRelease);
}

/** Call `done()` once `btn` has been held down (pointer, or Space/Enter) for `ms`; its .fill grows. */
function bindHold(btn, ms, done) {
  let timer = null, startedAt = 0, raf = null;
  const fill = btn.querySelector(".fill");
  const cancel = () => {
    clearTimeout(timer); timer = null;
    cancelAnimationFrame(raf);
    fill.style.width = "0%";
    btn.classList.remove("holding");
  };
  const grow = () => {
    fill.style.width = `${Math.min(100, ((Date.now() - startedAt) / ms) * 100)}%`;
    if (timer) raf = requestAnimationFrame(grow);
  };
  const begin = (ev) => {
    ev.preventDefault();
    if (timer) return;
    startedAt = Date.now();
    btn.classList.add("holding");
    timer = setTimeout(() => {
      timer = null;
      cancel();
      done();
    }, ms);
    raf = requestAnimationFrame(grow);
  };
  btn.addEventListener("pointerdown", begin);
  btn.addEventListener("keydown", (ev) => { if ((ev.key === " " || ev.key === "Enter") && !ev.repeat) begin(ev); });
  for (const e of ["pointerup", "pointerleave", "pointercancel", "keyup", "blur"]) btn.addEventListener(e, cancel);
}
