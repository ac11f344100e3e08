// Request bookkeeping: ids, messages, and the words for the coordinator's replies and error reports.
import assert from "node:assert/strict";
import { test } from "node:test";
import { Stamper } from "../static/js/protocol.js";
import { Requests, sentFeedback } from "../static/js/requests.js";

const requests = (client = "dash-1") => new Requests(client, new Stamper(client));
const reply = (fields) => JSON.stringify({ header: { sender: "coordinator" }, ...fields });

test("each request gets its own id and a message naming us as sender and reply topic", () => {
  const r = requests();
  const a = r.create("submit_job", "job", "job [1,1] → [8,8], 1.5 kg", { pickup: [1, 1], mass_kg: 1.5 });
  const b = r.create("set_goal", "goal", "goal [2, 2] for u1", { unit: "u1", target: [2, 2] });
  assert.equal(a.request_id, "dash-1-1");
  assert.equal(b.request_id, "dash-1-2");
  assert.equal(a.message.request_id, "dash-1-1");
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
  assert.ok(request_id.endsWith("x-1"));
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
