// Request bookkeeping: ids, messages, and the words for the coordinator's replies and error reports.
import assert from "node:assert/strict";
import { test } from "node:test";
import { Stamper } from "../static/js/protocol.js";
import { RETRY_MOST_MS, Requests, sentFeedback, sessionTag } from "../static/js/requests.js";

const requests = (client = "dash-1", options = {}) =>
  new Requests(client, new Stamper(client), { session: "s1", ...options });
const reply = (fields) => JSON.stringify({ header: { sender: "coordinator" }, ...fields });

test("each request gets its own id and a message naming us as sender and reply topic", () => {
  const r = requests();
  const a = r.create("submit_job", "job", "job [1,1] → [8,8], 1.5 kg", { pickup: [1, 1], mass_kg: 1.5 });
  const b = r.create("set_goal", "goal", "goal [2, 2] for u1", { unit: "u1", target: [2, 2] });
  assert.equal(a.request_id, "dash-1-s1-1");
  assert.equal(b.request_id, "dash-1-s1-2");
  assert.equal(a.message.request_id, "dash-1-s1-1");
  assert.equal(a.message.reply_to, "dash-1");
  assert.deepEqual(a.message.pickup, [1, 1]);
  assert.equal(a.message.mass_kg, 1.5);
  assert.equal(a.message.header.sender, "dash-1");
  assert.equal(a.message.header.seq, 0);
  assert.equal(r.create("submit_job", "job", "again", {}).message.header.seq, 1, "a counter per kind");
  assert.equal(b.message.header.seq, 0);
  assert.equal(r.pending.size, 3);
});

test("request ids stay within 64 characters, keeping the counter", () => {
  const client = `d${"x".repeat(63)}`;
  const { request_id } = requests(client).create("cancel_job", "cancel", "delete job j", { job_id: "j" });
  assert.equal(request_id.length, 64);
  assert.ok(request_id.endsWith("x-s1-1"));
});

test("ids differ between page loads with the same client id", () => {
  const stamper = new Stamper("dash-1");
  const one = new Requests("dash-1", stamper).create("cancel_job", "cancel", "delete job j", {});
  const two = new Requests("dash-1", stamper).create("cancel_job", "cancel", "delete job j", {});
  assert.match(sessionTag(), /^[0-9a-f]{6}$/);
  assert.notEqual(one.request_id, two.request_id); // one chance in 16 million to fail
});

test("a request without a reply is sent again, the same, backing off", () => {
  const r = requests("dash-1", { retryMs: 1000, waitMs: 60000 });
  const { request_id, message } = r.create("submit_job", "job", "job x", { mass_kg: 1 }, 0);
  const resent = [];
  for (let now = 0; now <= 30000; now += 500) {
    for (const m of r.due(now).resend) resent.push([now, m]);
  }
  assert.deepEqual(resent.map(([now]) => now), [1000, 3000, 7000, 15000, 25000]);
  for (const [, m] of resent) assert.deepEqual(m, { kind: "submit_job", message });
  assert.ok(25000 - 15000 <= RETRY_MOST_MS);
  r.reply(reply({ request_id, accepted: true, job_id: "j" }));
  assert.deepEqual(r.due(40000), { resend: [], feedback: [] }, "answered: nothing more goes out");
});

test("a request waited for too long is given up, and its form says so in words", () => {
  const r = requests("dash-1", { retryMs: 1000, waitMs: 10000 });
  const { request_id } = r.create("cancel_job", "cancel", "delete job j", { job_id: "j" }, 0);
  let tries = 1;
  for (let now = 0; now < 10000; now += 500) tries += r.due(now).resend.length;
  const { resend, feedback } = r.due(10000);
  assert.deepEqual(resend, []);
  assert.deepEqual(feedback, [{
    form: "cancel",
    kind: "refused",
    text: `delete job j: no reply from the coordinator to cancel_job ${request_id} after ${tries} tries over 10 s: is it running?`,
  }]);
  assert.equal(tries, 4); // at 0, 1, 3 and 7 s
  assert.equal(r.pending.size, 0);
  assert.deepEqual(r.reply(reply({ request_id, accepted: true })), { feedback: null, log: null }, "too late");
});

test("an accepted reply says so once, with the new job's id", () => {
  const r = requests();
  const { request_id } = r.create("submit_job", "job", "job [1,1] → [8,8], 1.5 kg", {});
  assert.deepEqual(r.reply(reply({ request_id, accepted: true, job_id: "job-7" })), {
    feedback: { form: "job", kind: "ok", text: "job [1,1] → [8,8], 1.5 kg: accepted (job job-7)" },
    log: null,
  });
  assert.deepEqual(r.reply(reply({ request_id, accepted: true })), { feedback: null, log: null }, "answered already");
  assert.equal(r.pending.size, 0);
});

test("a delete's reply does not repeat its job id", () => {
  const r = requests();
  const { request_id } = r.create("cancel_job", "cancel", "delete job job-4", { job_id: "job-4" });
  const { feedback } = r.reply(reply({ request_id, accepted: true, job_id: "job-4" }));
  assert.equal(feedback.text, "delete job job-4: accepted");
  assert.equal(feedback.form, "cancel");
});

test("a refusal gives the coordinator's reason in words", () => {
  const r = requests();
  const one = r.create("submit_job", "job", "job x", {}).request_id;
  const two = r.create("set_goal", "goal", "goal [2, 2] for u1", {}).request_id;
  assert.deepEqual(r.reply(reply({ request_id: one, accepted: false, reason: "too heavy" })).feedback,
    { form: "job", kind: "refused", text: "job x: refused — too heavy" });
  assert.equal(r.reply(reply({ request_id: two, accepted: false })).feedback.text,
    "goal [2, 2] for u1: refused — no reason given");
});

test("replies to requests we did not send, and malformed ones, change nothing", () => {
  const r = requests();
  r.create("submit_job", "job", "job x", {});
  assert.deepEqual(r.reply(reply({ request_id: "someone-1", accepted: true })), { feedback: null, log: null });
  for (const text of ["{oops", "null", "5", ""]) {
    assert.deepEqual(r.reply(text), { feedback: null, log: "ignored a malformed reply" }, text);
  }
  assert.equal(r.pending.size, 1);
});

test("an error report naming our request is shown on its form; the reply still follows", () => {
  const r = requests();
  const { request_id } = r.create("set_goal", "goal", "goal [2, 2] for unit2", {});
  const err = { header: { sender: "coordinator" }, topic: "lab/v1/requests/set_goal", reason: "target [2, 2] is a wall", request_id };
  assert.deepEqual(r.error(err), {
    feedback: { form: "goal", kind: "refused", text: "goal [2, 2] for unit2: refused — target [2, 2] is a wall" },
    log: "coordinator refused a message on lab/v1/requests/set_goal: target [2, 2] is a wall",
  });
  assert.equal(r.pending.size, 1, "kept waiting for the reply");
  assert.equal(r.reply(reply({ request_id, accepted: false, reason: "a wall" })).feedback.text,
    "goal [2, 2] for unit2: refused — a wall");
});

test("other error reports are only logged", () => {
  const r = requests();
  assert.deepEqual(r.error({ topic: "t", reason: "bad" }), { feedback: null, log: "? refused a message on t: bad" });
  assert.deepEqual(r.error({ header: { sender: "unit1" }, topic: "t", reason: "bad", request_id: "x-1" }),
    { feedback: null, log: "unit1 refused a message on t: bad" });
  assert.deepEqual(r.error(null), { feedback: null, log: null });
});

test("right after sending, the form says whether the broker has it", () => {
  assert.deepEqual(sentFeedback("job", "job x", true), { form: "job", kind: "pending", text: "job x: sent, waiting for the coordinator…" });
  assert.equal(sentFeedback("goal", "goal y", false).text, "goal y: queued: not connected to the broker");
});

test("a page answered on a topic of its own settles its request; an acknowledgement waits on the alerts process", () => {
  const r = requests("dash-1", { waitMs: 10000 });
  const { request_id } = r.create("job_history", "history", "job history", { since: "s" }, 0);
  assert.equal(r.settle(request_id), true);
  assert.equal(r.settle(request_id), false);
  assert.deepEqual(r.due(20000), { resend: [], feedback: [] }, "settled: sent no more");
  const ack = r.create("ack_alert", "alerts", "acknowledge estop a-1", { alert_id: "a-1" }, 0);
  const { feedback } = r.due(10000);
  assert.deepEqual(feedback, [{
    form: "alerts", kind: "refused",
    text: `acknowledge estop a-1: no reply from the alerts process to ack_alert ${ack.request_id} after 1 try over 10 s: is it running?`,
  }]);
});

test("an accepted removal says what became of the unit's job", () => {
  const r = requests();
  const { request_id } = r.create("remove_unit", "unit", "remove hv1", { unit: "hv1", reason: null });
  const said = r.reply(reply({ request_id, accepted: true, reason: "unit hv1 removed; job job-7 back in the queue", job_id: "job-7" }));
  assert.deepEqual(said.feedback, { form: "unit", kind: "ok", text: "remove hv1: accepted — unit hv1 removed; job job-7 back in the queue" });
  const refused = r.create("remove_unit", "unit", "remove u2", { unit: "u2", reason: null });
  const no = r.reply(reply({ request_id: refused.request_id, accepted: false, reason: "unit u2 is online and heard from" }));
  assert.equal(no.feedback.text, "remove u2: refused — unit u2 is online and heard from");
});
