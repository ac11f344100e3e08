// The page's side of the login: asks the dashboard server for the page's settings, logs in and
// out. No DOM: `fetch` is passed in, so node tests can stand in for the server.

/**
 * What /api/settings says: {kind: "settings", settings}, {kind: "login", message} when the
 * dashboard wants a login first, or {kind: "error", message} when it cannot be read.
 */
export async function loadSettings(fetchFn) {
  let res;
  try {
    res = await fetchFn("/api/settings", { credentials: "same-origin", cache: "no-store" });
  } catch (e) {
    return { kind: "error", message: `cannot load /api/settings from the dashboard server: ${e}` };
  }
  const body = await res.json().catch(() => null);
  if (res.status === 401) return { kind: "login", message: "" };
  if (!res.ok || !body) {
    return { kind: "error", message: `/api/settings answered ${res.status}: ${body?.error ?? "no settings"}` };
  }
  return { kind: "settings", settings: body };
}

/** Log in: {ok: true, user} or {ok: false, message} in words. */
export async function logIn(fetchFn, username, password) {
  let res;
  try {
    res = await fetchFn("/api/login", {
      method: "POST",
      credentials: "same-origin",
      // JSON, which a form on another site cannot send: the server takes nothing else.
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ username, password }),
    });
  } catch (e) {
    return { ok: false, message: `the dashboard server does not answer: ${e}` };
  }
  const body = await res.json().catch(() => null);
  if (res.ok && body?.user) return { ok: true, user: body.user };
  return { ok: false, message: body?.error ?? `login failed (${res.status})` };
}

/** Log out: true when the server has forgotten the session. */
export async function logOut(fetchFn) {
  try {
    const res = await fetchFn("/api/logout", {
      method: "POST",
      credentials: "same-origin",
      headers: { "Content-Type": "application/json" }, // the server takes JSON only
      body: "{}",
    });
    return res.ok;
  } catch {
    return false;
  }
}

/** MQTT.js options that log in as the account the settings name (none without accounts). */
export function mqttLogin(settings) {
  const login = settings.mqtt;
  return login ? { username: login.username, password: login.password } : {};
}
