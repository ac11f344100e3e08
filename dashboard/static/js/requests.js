// Operator requests and the coordinator's answers: request ids, the requests still waiting, and the
// words a form shows for a reply or an error report. Pure: no DOM, no network (the page publishes
// the messages made here and shows the feedback returned).
//
// Feedback is {form, kind, text}: `form` names the form that sent the request ("goal", "job",
// "cancel"), `kind` is "pending", "ok" or "refused".
//
// A loaded broker drops messages: a request is sent again, the same (same id: the coordinator
// answers a retry with its first answer, protocol.md §6), until its reply comes, backing off from
// `retryMs` to RETRY_MOST_MS; after `waitMs` in all the form says the coordinator did not answer.

export const RETRY_MS = 2000;
export const RETRY_MOST_MS = 10000;
export const WAIT_MS = 60000;
// Who answers a request: the coordinator, but for an alert's acknowledgement (protocol.md §6.7).
const ANSWERED_BY = { ack_alert: "the alerts process" };

/** A few random hex digits: request ids stay unique across page loads with one client id. */
export function sessionTag() {
  return Math.floor(Math.random() * 0x1000000).toString(16).padStart(6, "0");
}

export class Requests {
  /** `stamper` gives each message its header (protocol.js `Stamper`); `session` goes in every id. */
  constructor(clientId, stamper, { session = sessionTag(), retryMs = RETRY_MS, waitMs = WAIT_MS } = {}) {
    this.clientId = clientId;
    this.stamper = stamper;
    this.session = session;
    this.retryMs = retryMs;
    this.waitMs = waitMs;
    this.pending = new Map(); // request_id -> {form, what, kind, message, first, next, pause, tries}
    this.next = 1;
  }

  /**
   * A new request of `kind` from `form`, described to the operator as `what`; `body` holds its
   * fields. Returns {request_id, message}; the request, sent at `now` (ms), waits for its reply.
   */
  create(kind, form, what, body, now = Date.now()) {
    const request_id = `${this.clientId}-${this.session}-${this.next++}`.slice(-64);
    const message = { header: this.stamper.header(kind), request_id, reply_to: this.clientId, ...body };
    const pause = this.retryMs;
    this.pending.set(request_id, { form, what, kind, message, first: now, next: now + pause, pause, tries: 1 });
    return { request_id, message };
  }

  /**
   * What is due at `now` (ms): {resend: [{kind, message}], feedback: [...]}. Requests without a
   * reply are sent again, the same; one waiting `waitMs` in all is given up, and its form says so.
   */
  due(now) {
    const resend = [];
    const feedback = [];
    for (const [id, req] of this.pending) {
      if (now - req.first >= this.waitMs) {
        this.pending.delete(id);
        const tries = req.tries === 1 ? "1 try" : `${req.tries} tries`;
        const over = Math.round(this.waitMs / 1000);
        const who = ANSWERED_BY[req.kind] ?? "the coordinator";
        const text = `${req.what}: no reply from ${who} to ${req.kind} ${id} after ${tries} over ${over} s: is it running?`;
        feedback.push({ form: req.form, kind: "refused", text });
      } else if (now >= req.next) {
        req.tries += 1;
        req.pause = Math.min(2 * req.pause, RETRY_MOST_MS);
        req.next = now + req.pause;
        resend.push({ kind: req.kind, message: req.message });
      }
    }
    return { resend, feedback };
  }

  /**
   * The text of a reply on our reply topic. Returns {feedback, log}, either null: no feedback for a
   * request we are not waiting for (someone else's, or answered already).
   */
  reply(text) {
    let reply;
    try { reply = JSON.parse(text); } catch { reply = null; }
    if (typeof reply !== "object" || reply === null) return { feedback: null, log: "ignored a malformed reply" };
    const req = this.pending.get(reply.request_id);
    if (!req) return { feedback: null, log: null };
    this.pending.delete(reply.request_id);
    if (reply.accepted && req.kind === "remove_unit") { // its reason: what became of its job (§6.11)
      return { feedback: { form: req.form, kind: "ok", text: `${req.what}: accepted — ${reply.reason ?? "removed"}` }, log: null };
    }
    if (reply.accepted) {
      // "(job id)" tells which id a new job got; a delete already names its job.
      const extra = reply.job_id && req.form !== "cancel" ? ` (job ${reply.job_id})` : "";
      return { feedback: { form: req.form, kind: "ok", text: `${req.what}: accepted${extra}` }, log: null };
    }
    const reason = reply.reason ?? "no reason given";
    return { feedback: { form: req.form, kind: "refused", text: `${req.what}: refused — ${reason}` }, log: null };
  }

  /**
   * The answer to request `requestId` came on a topic of its own (a page of the history or the
   * audit): it is sent no more. True when it was waiting.
   */
  settle(requestId) {
    return this.pending.delete(requestId);
  }

  /**
   * An error report from the `errors` topic (parsed). Returns {feedback, log}: feedback when it
   * names a request of ours still waiting, and always a line for the message log.
   */
  error(err) {
    if (!err) return { feedback: null, log: null };
    const req = err.request_id ? this.pending.get(err.request_id) : null;
    // Kept pending: the coordinator's reply follows with the reason alone (the error report names
    // the message type too); whichever comes, the operator sees why.
    const feedback = req ? { form: req.form, kind: "refused", text: `${req.what}: refused — ${err.reason}` } : null;
    return { feedback, log: `${err.header?.sender ?? "?"} refused a message on ${err.topic}: ${err.reason}` };
  }
}

/** What a form says right after sending `what`, with or without the broker. */
export function sentFeedback(form, what, connected) {
  const note = connected ? "sent, waiting for the coordinator…" : "queued: not connected to the broker";
  return { form, kind: "pending", text: `${what}: ${note}` };
}
