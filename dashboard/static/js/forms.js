// The goal, job and zone forms (and the queue's delete buttons): what they check before sending,
// the requests they make, and what they tell the operator. The checks and the words are pure
// functions (testable under node); `Forms` reads and fills the page's forms.

import { parseWhere, pickedFor, resolveWhere, whereText } from "./places.js";
import { ID_RE } from "./protocol.js";
import { closeZoneRequest, rectText } from "./zones.js";

const NO_MAP = "no map yet: waiting for the coordinator's fleet/map";

/**
 * A set_goal request for `unit` to `target` ([x, y], or null to clear its goal), checked against
 * the FleetView `view`: {what, body}, or {error} in words.
 */
export function goalRequest(view, unit, target) {
  if (!unit) return { error: "choose a unit first (list or map)" };
  if (target && !view.map) return { error: NO_MAP };
  if (target && !view.onMap(target[0], target[1])) return { error: `[${target}] is not a square of the map` };
  const what = target ? `goal [${target[0]}, ${target[1]}] for ${unit}` : `clear the goal of ${unit}`;
  return { what, body: { unit, target } };
}

/**
 * The job form's fields ({pickup, dropoff, mass, priority, job_id}, each with a `.value`):
 * pickup and dropoff as typed (a place's name or a square X,Y), the rest as numbers.
 */
export function readJobForm(f) {
  return {
    pickup: f.pickup.value,
    dropoff: f.dropoff.value,
    mass: Number(f.mass.value),
    priority: Number(f.priority.value || 0),
    jobId: f.job_id.value.trim() || null,
  };
}

/**
 * A submit_job request from the job form's values (`readJobForm`): {what, body}, or {error}.
 * Its pickup and dropoff go as the place names typed (the coordinator resolves them) or as
 * squares [x, y]; a name the map's places do not have, or of another kind, is refused here.
 */
export function jobRequest(view, { pickup, dropoff, mass, priority, jobId }) {
  if (!view.map) return { error: NO_MAP };
  const ends = {};
  for (const [role, text] of [["pickup", pickup], ["dropoff", dropoff]]) {
    const where = resolveWhere(view.places, parseWhere(text), role);
    if (where.error) return { error: where.error };
    const [x, y] = where.square;
    if (!view.onMap(x, y)) return { error: `${role} [${where.square}] is not a square of the map` };
    ends[role] = where;
  }
  if (!(mass > 0) || !Number.isFinite(mass)) return { error: "mass must be more than 0 kg" };
  if (!Number.isInteger(priority) || priority < 0 || priority > 100) return { error: "priority must be a whole number 0–100" };
  if (jobId && !ID_RE.test(jobId)) return { error: "job id: letters, digits, _ . - only (max 64)" };
  const said = (w) => whereText(w.square, w.place?.name);
  return {
    what: `job ${said(ends.pickup)} → ${said(ends.dropoff)}, ${mass} kg`,
    body: { pickup: ends.pickup.value, dropoff: ends.dropoff.value, mass_kg: mass, priority, job_id: jobId },
  };
}

const COMMAND_WORDS = {
  pause: "pause", resume: "resume", out_of_service: "take out of service", in_service: "bring into service",
  charge: "send to charge",
};

/** A control_unit request for a unit row's buttons (protocol.md §6.4). */
export function controlRequest(unit, command) {
  return { what: `${COMMAND_WORDS[command] ?? command} ${unit}`, body: { unit, command } };
}

/** A remove_unit request for a lost unit's "remove" button (protocol.md §6.11). */
export function removeRequest(unit) {
  return { what: `remove ${unit}`, body: { unit, reason: null } };
}

/** What the page asks before it removes a unit: the operator confirms it is off the floor. */
export function removeQuestion(unit) {
  return `Remove ${unit} for good?\n\nOnly for a lost unit you have made sure is physically off the floor: ` +
    "its squares are freed, its job goes back to the queue (or fails, if it carried the item), and it is audited. " +
    "Should it come back, it joins the fleet as a new unit.";
}

export const FEEDBACK_MS = 10000; // how long an answer stays under its form: then it is stale

/** A cancel_job request for the queue's "delete" button. */
export function cancelRequest(jobId) {
  return { what: `delete job ${jobId}`, body: { job_id: jobId } };
}

/**
 * What the job form says once a square has been clicked for its pickup or its dropoff; `name`:
 * the place picked there, if one was.
 */
export function pickedPickup(sq, name = null) { return `pickup ${whereText(sq, name)}: now click the dropoff square`; }
export function pickedDropoff(sq, name = null) { return `dropoff ${whereText(sq, name)}: set the mass and press “queue job”`; }

/** The zone form's words above its fields, for the rectangle drawn. */
export function zoneAsk(rect) {
  return `close ${rectText(rect)}:`;
}

/**
 * The forms on the page. `send(kind, form, what, body)` publishes a request; `onUnitChosen(id)`
 * hears the goal form's unit choice (null: none); `onPickField(field)` that the operator focused
 * the job form's pickup or dropoff field; `onZoneDone()` that the zone drawn was sent or
 * cancelled.
 */
export class Forms {
  constructor(view, { send, onUnitChosen, onPickField = () => {}, onZoneDone = () => {} }) {
    this.view = view;
    this.send = send;
    this.onUnitChosen = onUnitChosen;
    this.onPickField = onPickField;
    this.onZoneDone = onZoneDone;
    this.goal = document.querySelector("#goal-form");
    this.job = document.querySelector("#job-form");
    this.zone = document.querySelector("#zone-form");
    this.zoneRect = null; // the rectangle the zone form closes, {first, last}
    this.placesShown = null; // the place index the job form's lists offer
    this.timers = {}; // form -> the timer that clears its answer
  }

  bind() {
    this.goal.unit.addEventListener("change", (ev) => this.onUnitChosen(ev.target.value || null));
    this.goal.addEventListener("submit", (ev) => {
      ev.preventDefault();
      this.sendGoal(this.goal.unit.value, [Number(this.goal.x.value), Number(this.goal.y.value)]);
    });
    document.querySelector("#goal-clear").addEventListener("click", () => this.sendGoal(this.goal.unit.value, null));
    this.job.addEventListener("submit", (ev) => { ev.preventDefault(); this.submitJob(); });
    // A click on the map fills the field focused last (clicks.js pickInto).
    for (const field of ["pickup", "dropoff"]) this.job[field].addEventListener("focus", () => this.onPickField(field));
    this.zone.addEventListener("submit", (ev) => { ev.preventDefault(); this.submitZone(); });
    document.querySelector("#zone-cancel").addEventListener("click", () => this.endZone());
    this.zone.addEventListener("keydown", (ev) => { if (ev.key === "Escape") this.endZone(); });
    // Editing a form again makes its last answer stale.
    for (const [name, form] of [["goal", this.goal], ["job", this.job], ["zone", this.zone]]) {
      form.addEventListener("input", () => this.feedback(name, "", ""));
    }
  }

  /**
   * Show `text` under a form ("goal", "job", "cancel" or "unit"); `kind` colours it. An answer
   * clears itself after FEEDBACK_MS; one still waiting ("pending") stays until answered.
   */
  feedback(form, kind, text) {
    const el = document.querySelector(`#${form}-feedback`);
    el.dataset.kind = kind;
    el.textContent = text;
    clearTimeout(this.timers[form]);
    if (text && kind !== "pending") {
      this.timers[form] = setTimeout(() => { if (el.textContent === text) this.feedback(form, "", ""); }, FEEDBACK_MS);
    }
  }

  controlUnit(unit, command) {
    const req = controlRequest(unit, command);
    this.send("control_unit", "unit", req.what, req.body);
  }

  removeUnit(unit) {
    const req = removeRequest(unit);
    this.send("remove_unit", "unit", req.what, req.body);
  }

  sendGoal(unit, target) {
    const req = goalRequest(this.view, unit, target);
    if (req.error) { this.feedback("goal", "refused", req.error); return; }
    this.send("set_goal", "goal", req.what, req.body);
  }

  submitJob() {
    const req = jobRequest(this.view, readJobForm(this.job));
    if (req.error) { this.feedback("job", "refused", req.error); return; }
    this.send("submit_job", "job", req.what, req.body);
  }

  /**
   * A rectangle was drawn on the map: the zone form asks its name and reason, over the map's
   * `edge` ("top" or "bottom").
   */
  askZone(rect, edge = "top") {
    this.zoneRect = rect;
    document.querySelector("#zone-tools").dataset.edge = edge;
    this.zone.querySelector("#zone-rect").textContent = zoneAsk(rect);
    this.zone.reset();
    this.zone.hidden = false;
    this.feedback("zone", "", "");
    this.zone.elements.name.focus();
  }

  submitZone() {
    const f = this.zone.elements;
    const req = closeZoneRequest(this.view, { ...(this.zoneRect ?? {}), name: f.name.value, reason: f.reason.value });
    if (req.error) { this.feedback("zone", "refused", req.error); return; }
    this.send("close_zone", "zone", req.what, req.body);
    this.endZone(false);
  }

  /** The zone form goes (sent, or cancelled: then its words go too), and the rectangle drawn. */
  endZone(cancelled = true) {
    this.zone.hidden = true;
    this.zoneRect = null;
    if (cancelled) this.feedback("zone", "", "");
    this.onZoneDone();
  }

  cancelJob(jobId) {
    const req = cancelRequest(jobId);
    this.send("cancel_job", "cancel", req.what, req.body);
  }

  // ---- squares clicked on the map ----

  /** A goal square clicked for the unit the goal form names: filled in and sent. */
  goalAt(sq) {
    const f = this.goal;
    f.x.value = sq[0]; f.y.value = sq[1];
    this.sendGoal(f.unit.value, sq);
  }

  /** A square clicked for the pickup: the place there (of kind pickup), else the square. */
  pickupAt(sq) {
    const picked = pickedFor(this.view.places, sq, "pickup");
    this.job.pickup.value = picked.text;
    this.feedback("job", "info", pickedPickup(sq, picked.name));
  }

  dropoffAt(sq) {
    const picked = pickedFor(this.view.places, sq, "dropoff");
    this.job.dropoff.value = picked.text;
    this.feedback("job", "info", pickedDropoff(sq, picked.name));
    this.job.mass.focus();
  }

  /** The job form's lists offer the map's pickups and dropoffs (refilled when the map changes). */
  syncPlaces(index) {
    if (this.placesShown === index) return;
    this.placesShown = index;
    for (const role of ["pickup", "dropoff"]) {
      // Each offered by its name, its square beside it ("A3" · "[3, 4]").
      const options = index.namesOf(role).map((name) => new Option(whereText(index.byName.get(name).square), name));
      document.querySelector(`#${role}-places`).replaceChildren(...options);
    }
  }

  // ---- the goal form's unit choice ----

  /** The goal form names unit `id` (chosen in the list or on the map). */
  showUnit(id) {
    this.goal.unit.value = id;
  }

  /** One choice per unit, in order; the choice stays, else `selected`, else the first unit. */
  syncUnits(ids, selected) {
    const sel = this.goal.unit;
    const current = sel.value;
    if ([...sel.options].map((o) => o.value).join() !== ids.join()) {
      sel.replaceChildren(...ids.map((id) => new Option(id, id)));
      sel.value = ids.includes(current) ? current : (selected ?? ids[0] ?? "");
    }
  }
}
