// Operator requests and the coordinator's answers: request ids, the requests still waiting, and the
// words a form shows for a reply or an error report. Pure: no DOM, no network (the page publishes
// the messages made here and shows the feedback returned).
//
// Feedback is {form, kind, text}: `form` names the form that sent the request ("goal", "job",
// "cancel"), `kind` is "pending", "ok" or "refused".

export class Requests {
  /** `stamper` gives each message its header (protocol.js `Stamper`). */
  constructor(clientId, stamper) {
    this.clientId = clientId;
    this.stamper = stamper;
    this.pending = new Map(); // request_id -> {form, what}
    this.next = 1;
  }

  /**
   * A new request of `kind` from `form`, described to the operator as `what`; `body` holds its
   * fields. Returns {request_id, message}; the request waits for its reply from now on.
   */
  create(kind, form, what, body) {
    const request_id = `${this.clientId}-${this.next++}`.slice(-64);
    const message = { header: this.stamper.header(kind), request_id, reply_to: this.clientId, ...body };
    this.pending.set(request_id, { form, what });
    return { request_id, message };
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
    if (reply.accepted) {
      // "(job id)" tells which id a new job got; a delete already names its job.
      const extra = reply.job_id && req.form !== "cancel" ? ` (job ${reply.job_id})` : "";
      return { feedback: { form: req.form, kind: "ok", text: `${req.what}: accepted${extra}` }, log: null };
    }
    const reason = reply.reason ?? "no reason given";
    return { feedback: { form: req.form, kind: "refused", text: `${req.what}: refused — ${reason}` }, log: null };
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
