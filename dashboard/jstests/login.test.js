// The page's login calls against a stand-in for the dashboard server.
import assert from "node:assert/strict";
import { test } from "node:test";
import { loadSettings, logIn, logOut, mqttLogin } from "../static/js/login.js";

/** A fetch that answers `status` with `body` and records what it was asked. */
function server(status, body) {
  const calls = [];
  const fetchFn = async (url, options = {}) => {
    calls.push({ url, options });
    return {
      status,
      ok: status >= 200 && status < 300,
      json: async () => { if (body === undefined) throw new SyntaxError("no JSON"); return body; },
    };
  };
  return { fetchFn, calls };
}

test("a 401 from /api/settings asks for the login", async () => {
  const { fetchFn } = server(401, { error: "log in to see the fleet" });
  assert.deepEqual(await loadSettings(fetchFn), { kind: "login", message: "" });
});

test("settings come through; other answers are errors in words", async () => {
  const settings = { broker_ws: "wss://h:9001", mqtt: { username: "operator", password: "p" } };
  assert.deepEqual(await loadSettings(server(200, settings).fetchFn), { kind: "settings", settings });
  const broken = await loadSettings(server(500, undefined).fetchFn);
  assert.equal(broken.kind, "error");
  assert.match(broken.message, /500/);
  const down = await loadSettings(async () => { throw new TypeError("Failed to fetch"); });
  assert.equal(down.kind, "error");
  assert.match(down.message, /Failed to fetch/);
});

test("login posts JSON and reports the server's words when refused", async () => {
  const ok = server(200, { user: "operator" });
  assert.deepEqual(await logIn(ok.fetchFn, "operator", "secret"), { ok: true, user: "operator" });
  const [call] = ok.calls;
  assert.equal(call.url, "/api/login");
  assert.equal(call.options.method, "POST");
  assert.equal(call.options.headers["Content-Type"], "application/json");
  assert.deepEqual(JSON.parse(call.options.body), { username: "operator", password: "secret" });
  const refused = server(401, { error: "wrong user name or password" });
  assert.deepEqual(await logIn(refused.fetchFn, "operator", "nope"), {
    ok: false, message: "wrong user name or password",
  });
  const throttled = await logIn(server(429, undefined).fetchFn, "a", "b");
  assert.deepEqual(throttled, { ok: false, message: "login failed (429)" });
});

test("logout posts and says whether the server forgot the session", async () => {
  const out = server(200, { ok: true });
  assert.equal(await logOut(out.fetchFn), true);
  assert.deepEqual([out.calls[0].url, out.calls[0].options.method], ["/api/logout", "POST"]);
  assert.equal(await logOut(async () => { throw new TypeError("down"); }), false);
});

test("MQTT.js logs in only when the settings carry an account", () => {
  assert.deepEqual(mqttLogin({ mqtt: null }), {});
  assert.deepEqual(mqttLogin({ mqtt: { username: "ann", password: "pw" } }), {
    username: "ann", password: "pw",
  });
});
