// Hitch terminal: the operator page of the hitch service. Plain ES2020, no build step.
//
// Everything shown comes from the service: `state` messages (what <prefix>/state publishes, 50 Hz)
// and `event` messages over one WebSocket; every command goes to the service's own API handler
// (`{id, key, payload}` → `{type: "reply", id, ok, data}`). The page keeps no state of its own
// except what it draws, the held jog buttons, the jog speed and its own levelling session.
//
// Units: the API is SI (m, rad, s). The page shows and takes mm and — a setting of this browser
// (localStorage `hitch.angleUnit`, the "Angles" button) — mrad (the thesis's unit, the default) or
// degrees; lateral position as "left/right n mm", lift as % of its stroke. Conversions happen only
// in `show*`, in the goto form and in `displayUnits`, which rewrites the service's SI numbers in
// refusals and events.
//
// The hitch picture: `terminal` (once) and `view` messages (≤ 15 Hz) carry the model's points for
// the measured and the target actuators, computed by the server (bridge/web/view.py).
//
// Login: with access control on (`GET /api/session` says `login`), the page asks for a user and
// password (`POST /api/login`); the session lives in an HttpOnly cookie, and every command carries
// the session's CSRF token (`csrf` in a WebSocket command). STOP never needs a login.
"use strict";

(() => {
  const JOG_PERIOD_MS = 80;        // resend period while a jog button or key is held
  const JOG_TTL_MS = 250;          // the service stops the jog this long after the last command
  // m/s, rad/s at 100 % jog speed: the service's jog speed limits (config limits.jog_velocity), these until it answers
  const JOG_MAX_FALLBACK = { x: 0.05, z: 0.15, roll: 0.15, pitch: 0.15 };
  const jogMax = (dof) => {
    const lim = ui.config && ui.config.limits && ui.config.limits.jog_velocity;
    return lim && Number.isFinite(lim[dof]) && lim[dof] > 0 ? lim[dof] : JOG_MAX_FALLBACK[dof];
  };
  const LEVEL_PERIOD_MS = 100;     // levelling: a track/setpoint {roll: 0} this often while on and visible
  const REPEATED_KEYS = new Set(["jog", "track/setpoint"]);   // sent periodically: never queued behind a stall
  const LEVEL_TTL_MS = 500;        // the service brakes this long after the last setpoint (the dead-man)
  const STATE_STALE_MS = 500;      // no state for this long: the service is not publishing
  const ECU_STALE_S = 0.2;         // s: an ECU measurement older than this is not live (the service's default limit)
  const REQUEST_TIMEOUT_MS = 15000;
  const KIN_CAUTION_S = 2.0, KIN_DANGER_S = 0.5;   // page colours for the kinematic margin (assumed)
  // ECU pill: the valves drive while the reference moves or the measurement is farther from the
  // reference than this share of each actuator's stroke range (a few AD counts; the ECU's own
  // hold band is its settle band of ±1 count), otherwise the ECU holds (valves at zero)
  const ECU_HOLD_FRACTION = 0.005;
  const REF_MOVING = 1e-6;         // m/s, rad/s: a reference velocity above this is motion
  const DOFS = ["x", "z", "roll", "pitch"];
  const KEYS = { ArrowLeft: ["x", 1], ArrowRight: ["x", -1], ArrowUp: ["z", 1], ArrowDown: ["z", -1],
    KeyD: ["roll", 1], KeyA: ["roll", -1], KeyW: ["pitch", 1], KeyS: ["pitch", -1] };
  const MODE_NAMES = { auto: "Automatic", attach: "Implement attach", manual: "Manual", transport: "Transport",
    config: "Configuration" };
  const HELP = {
    main: ["The main screen: live pose (x, z bars; roll, pitch needles), actuator strokes, margins and the commands.",
      "Pick an operating mode at the top. STOP (or Esc / Space) stops any motion from any mode."],
    auto: ["Cartesian control of the implement: jog x, z, roll and pitch while a button or key is held, go to a pose, recall presets, run maneuvers.",
      "Near a workspace face the motion towards it stops and “Control limited” names the limit; motion away from it stays free.",
      "Keys: ← → lateral x, ↑ ↓ height z, A D roll, S W pitch. Esc or Space: STOP."],
    attach: ["Implement attach: slow jog only (a quarter of the normal speed) for hitching an implement; goto, presets and maneuvers are refused.",
      "Stay clear of the lower links. Release the button to stop."],
    manual: ["Manual: the service moves nothing; each cylinder is run from the tractor's own controls with only its per-cylinder limits.",
      "Risky with an implement attached. Switch back to Automatic for Cartesian control."],
    transport: ["Transport: the hitch is held for road travel; all motion is refused. STOP stays available."],
    config: ["Configuration: the service's settings (profile, implement category, limits, control rate) are shown below; they are changed in the service's config file and take effect at its next start.",
      "The jog speed slider on the Jog tab is this page's joystick sensitivity. No motion in this mode."],
  };
  const ANGLE_KEY = "hitch.angleUnit";
  const ANGLES = { mrad: { k: 1000, digits: 1, unit: "mrad" }, deg: { k: 180 / Math.PI, digits: 2, unit: "deg" } };
  const units = { angle: "mrad" };
  try { if (localStorage.getItem(ANGLE_KEY) === "deg") units.angle = "deg"; } catch (e) { /* storage off: mrad */ }
  const $ = (sel) => document.querySelector(sel);
  const $$ = (sel) => Array.from(document.querySelectorAll(sel));
  const svgNS = "http://www.w3.org/2000/svg";

  const ui = {
    config: null, state: null, lastStateMs: 0, drawn: true, frames: 0, rate: 0,
    presets: [], maneuvers: [], maneuverSteps: {}, connected: false, closedReason: "", gotoId: null,
    outcomes: new Map(),   // an outcome can reach the page before its request's reply
    // maneuver id → its end [text, ok] (kept for a run whose reply is still on its way), and the maneuver whose
    // run this page shows under the list: an older one's end (the one a Run replaced) is not drawn over it
    maneuverEnds: new Map(), maneuverShown: null,
    implementSelections: 0, implementSelected: null,   // implement_selected events handled, and the last one's
    session: null,   // GET /api/session: {login, authenticated, user, role, csrf}
  };
  // the hitch picture: `terminal` info (once), the newest `view` message, the built views
  const hv = { info: null, msg: null, rear: null, side: null, drawn: null };

  // ------------------------------------------------------------------ formatting
  const fmt = (v, digits = 0) => (v === null || v === undefined || !Number.isFinite(v)) ? "—" : v.toFixed(digits);
  // no "-0" ("roll -0" in the preset list): a value that rounds to zero is shown as 0
  const fmtNoNegZero = (v, digits = 0) => { const t = fmt(v, digits); return /^-0(\.0*)?$/.test(t) ? t.slice(1) : t; };
  const show_mm = (m) => `${fmt(m * 1000, 1)} mm`;
  const angleUnit = () => ANGLES[units.angle];
  const show_angle = (rad) => `${fmt(rad * angleUnit().k, angleUnit().digits)} ${angleUnit().unit}`;
  const show_mrad = (rad) => `${fmt(rad * 1000, 1)} mrad`;
  // lateral position: +x is the driver's left
  const show_x = (m) => !Number.isFinite(m) ? "—" : Math.abs(m) < 0.00005 ? "centre 0.0 mm" : `${m > 0 ? "left" : "right"} ${fmt(Math.abs(m) * 1000, 1)} mm`;
  const isLength = (k) => k === "x" || k === "z";
  const dofK = (k) => isLength(k) ? 1000 : angleUnit().k;           // SI → display factor
  const dofDigits = (k) => isLength(k) ? 1 : angleUnit().digits;
  const dofUnit = (k) => isLength(k) ? "mm" : angleUnit().unit;
  const showDof = (k, v) => isLength(k) ? show_mm(v) : show_angle(v);
  const strokeOf = (n) => (ui.config && ui.config.limits && ui.config.limits.strokes && ui.config.limits.strokes[n]) || null;
  // lift: % of its stroke (the lift-arm angle in the tooltip); the other actuators in mm
  const liftPercent = (v) => { const r = strokeOf("lift"); return r ? 100 * (v - r[0]) / (r[1] - r[0]) : NaN; };
  const showActuator = (n, v) => n === "lift" ? `${fmt(liftPercent(v), 1)} %` : show_mm(v);

  // The service's sentences carry SI numbers ("goal.z = 0.5 m … (z from -0.2163 to 0.3117 m)",
  // "workspace:z:max = 0.3117"); the operator reads mm and mrad: every length [m] and angle [rad]
  // (with its rates) is rewritten ×1000, and bare numbers after a DOF name (x, z: mm; roll, pitch:
  // mrad) too. Times, percentages and counts stay.
  const NUM = String.raw`[-−+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?`;
  const UNIT = String.raw`(m|rad)(\/s²|\/s\^2|\/s2|\/s)?(?![A-Za-z0-9_²])`;
  // an SI number in unit u ("m" or "rad") → the display unit (mm; mrad or deg)
  const milli = (t, u = "m") => {
    const k = u === "rad" ? angleUnit().k : 1000, v = Number(t.replace("−", "-")) * k;
    return Number.isFinite(v) ? String(Number(v.toFixed(2))) : t;
  };
  const milliUnit = (u, rate) => `${u === "rad" ? angleUnit().unit : "mm"}${rate || ""}`;
  // The maneuver editor's scripts are in metres and radians (docs/maneuvers.md): its refusals keep the service's
  // SI numbers, a bare one after a DOF name gets its unit ("goal.z = 0.5 m" — "goal.z = 500 mm" for a typed
  // 0.5 confused an operator)
  function siUnits(text) {
    if (typeof text !== "string") return text;
    return text.replace(new RegExp(String.raw`(\b(?:workspace:)?(x|z|roll|pitch)(?::(?:min|max))?\s*(?:=|reaches)\s*)(${NUM})(?![\d.eE])(?!\s*(?:mm|mrad|m|rad|s|ms|deg|counts?)(?![A-Za-z])|\s*[%°])`, "g"),
      (_, head, dof, a) => `${head}${a} ${isLength(dof) ? "m" : "rad"}`);
  }
  function displayUnits(text) {
    if (typeof text !== "string") return text;
    const guard = String.raw`(?<![\w.])`;
    // the service's "did you mean mm / degrees / mrad?" hints are for SI callers: this page's fields already
    // take mm and the chosen angle unit
    let t = text.replace(/;?\s*did you mean (?:mm|degrees|mrad)\?[^;)]*(?:;\s*or (?:degrees|mrad)\?[^;)]*)?/g, "");
    // [a, b] m · a … b m · from a to b m · >= a and <= b m
    t = t.replace(new RegExp(String.raw`\[\s*(${NUM})\s*,\s*(${NUM})\s*\]\s*${UNIT}`, "g"),
      (_, a, b, u, r) => `[${milli(a, u)}, ${milli(b, u)}] ${milliUnit(u, r)}`);
    t = t.replace(new RegExp(String.raw`${guard}(${NUM})(\s*(?:…|\.\.\.?|–|\bto\b|\band\b\s*[<>]=?)\s*)(${NUM})\s*${UNIT}`, "g"),
      (_, a, mid, b, u, r) => `${milli(a, u)}${mid}${milli(b, u)} ${milliUnit(u, r)}`);
    t = t.replace(new RegExp(String.raw`${guard}(${NUM})\s*${UNIT}`, "g"), (_, a, u, r) => `${milli(a, u)} ${milliUnit(u, r)}`);
    // bare numbers named by a DOF: "goal.z = 0.5", "z reaches 0.31", "workspace:z:max = 0.3117"
    t = t.replace(new RegExp(String.raw`(\b(?:workspace:)?(x|z|roll|pitch)(?::(?:min|max))?\s*(?:=|reaches)\s*)(${NUM})(?![\d.eE])(?!\s*(?:mm|mrad|m|rad|s|ms|deg|counts?)(?![A-Za-z])|\s*[%°])`, "g"),
      (_, head, dof, a) => `${head}${milli(a, isLength(dof) ? "m" : "rad")} ${dofUnit(dof)}`);
    return t;
  }
  window.hitchTerminal = { displayUnits, siUnits };   // for the browser test (the page keeps its CSP: no eval)

  // A refusal naming limits by code gets their operator words appended (the terminal's table:
  // "… stroke:top:max … — top link at its stroke end (longest)").
  function inWords(text) {
    const table = hv.info && hv.info.words;
    if (typeof text !== "string" || !table) return text;
    const found = [];
    for (const code of Object.keys(table).sort((a, b) => b.length - a.length)) {
      const re = new RegExp(String.raw`(?<![\w:])${code.replace(/[.*+?^${}()|[\]\\]/g, "\\$&")}(?![\w:])`);
      if (table[code] && re.test(text) && !found.includes(table[code])) found.push(table[code]);
    }
    return found.length ? `${text} — ${found.join("; ")}` : text;
  }

  function log(text, isError = false) {
    const f = $("#log");
    const shown = displayUnits(text);
    f.textContent = `${new Date().toLocaleTimeString()}  ${isError ? inWords(shown) : shown}`;
    f.title = f.textContent;
    f.classList.toggle("err", isError);
  }

  // ------------------------------------------------------------------ connection
  class Link {
    constructor() { this.ws = null; this.nextId = 1; this.pending = new Map(); this.retryMs = 500; }

    connect() {
      const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
      this.ws = ws;
      ws.onopen = () => { this.retryMs = 500; ui.connected = true; ui.closedReason = ""; onConnected(); };
      ws.onmessage = (ev) => this.dispatch(ev.data);
      ws.onclose = (ev) => {
        const was = ui.connected;
        ui.connected = false;
        // the close of the open connection says why; the failed reconnects after it do not overwrite that (a
        // service stopped cleanly, 1001, read "the connection … was lost" after the first retry, an operator's trial)
        if (was || !ui.closedReason) {
          ui.closedReason = ev.code === 1001 ? "the hitch service stopped" : "the connection to the hitch service was lost";
        }
        for (const [, p] of this.pending) p.resolve({ ok: false, data: { error: "disconnected", message: "not connected to the service" } });
        this.pending.clear();
        jog.releaseAll();
        level.halt("the connection was lost: setpoints stopped, the service brakes");
        renderConnection();
        if (ev.code === 4401) { checkSession(ev.reason || "session ended"); return; }   // logged out or expired
        // with a login: ask the server whether the session lives on; if not (the service restarted: it keeps no
        // sessions), say so on the login form (it came up blank after a restart: a trial)
        const ended = ui.session && ui.session.authenticated ? "your session ended (the service restarted, or the login expired): log in again" : "";
        setTimeout(() => (ui.session && ui.session.login ? checkSession(ended) : this.connect()), this.retryMs);
        this.retryMs = Math.min(this.retryMs * 2, 4000);
      };
    }

    dispatch(text) {
      let msg;
      try { msg = JSON.parse(text); } catch (e) { return; }
      if (msg.type === "state") onState(msg.data);
      else if (msg.type === "event") onEvent(msg.data);
      else if (msg.type === "hello") ui.hello = msg.data;
      else if (msg.type === "terminal") onTerminal(msg.data);
      else if (msg.type === "view") onView(msg.data);
      else if (msg.type === "reply") {
        const p = this.pending.get(msg.id);
        if (p) { this.pending.delete(msg.id); clearTimeout(p.timer); p.resolve({ ok: msg.ok, data: msg.data || {} }); }
      }
    }

    // One API call: resolves {ok, data}; never rejects.
    request(key, payload = {}) {
      if (!this.ws || this.ws.readyState !== WebSocket.OPEN) {
        return Promise.resolve({ ok: false, data: { error: "disconnected", message: `${key}: not connected to the service` } });
      }
      // A repeated command (a held jog, levelling's setpoints) is not queued behind a stalled connection: the
      // service brakes at its ttl meanwhile, and a stall's backlog sent at once looked like a flood (the server
      // closes a page above 100 commands a second, a review).
      if (REPEATED_KEYS.has(key) && this.ws.bufferedAmount > 0) {
        return Promise.resolve({ ok: false, data: { error: "disconnected", message: `${key}: not sent, the connection is backed up` } });
      }
      const id = this.nextId++;
      return new Promise((resolve) => {
        const timer = setTimeout(() => {
          this.pending.delete(id);
          resolve({ ok: false, data: { error: "timeout", message: `${key}: no answer within ${REQUEST_TIMEOUT_MS / 1000} s` } });
        }, REQUEST_TIMEOUT_MS);
        this.pending.set(id, { resolve, timer });
        const cmd = { id, key, payload };
        if (ui.session && ui.session.csrf) cmd.csrf = ui.session.csrf;   // every command carries the CSRF token
        this.ws.send(JSON.stringify(cmd));
      });
    }
  }
  const link = new Link();

  // Replies can come back out of order (the server runs each command as its own task): a list asked for earlier
  // whose answer comes after a later one's is not drawn over it. `asking(kind)` before the call; the function it
  // returns says whether the answer is still the newest of its kind (then it is the one shown).
  const answered = {};
  function asking(kind) {
    const mine = (answered[kind] = answered[kind] || { asked: 0, shown: 0 }).asked += 1;
    return () => { const a = answered[kind]; if (mine < a.shown) return false; a.shown = mine; return true; };
  }

  async function call(key, payload, quiet = false) {
    const r = await link.request(key, payload);
    if (!r.ok) conflictRefusal(r.data);
    if (!r.ok && !quiet) log(r.data.message || `${key}: ${r.data.error}`, true);
    return r;
  }

  // ------------------------------------------------------------------ two services on one prefix
  // The service announces `prefix_conflict` {message, other, ends} when it meets another service on its key
  // prefix: both brake; the later one (`ends`) refuses every request but stop and ends itself. A red banner
  // says so until the operator dismisses it (a grey footer line, overwritten by the next event, was all
  // before: an operator's trial). A refusal "…: refused, the service ends: …" raises it too.
  function showConflict(c) {
    ui.conflict = c;
    const other = c.other ? ` (instance ${c.other})` : "";
    const prefix = (ui.hello && ui.hello.prefix) || (ui.config && ui.config.prefix);
    const on = prefix ? `prefix “${prefix}”` : "this prefix";
    $("#conflict-text").textContent = `Prefix conflict: another hitch service${other} serves ${on} as well — ` +
      "a goto or STOP could reach either tractor. Both braked to rest. " +
      (c.ends ? "This page's service refuses every command but STOP and ends itself. "
        : "This page's service serves on; the other one ends itself. ") +
      "Stop one of the two services on this prefix (or give one its own prefix) before moving the hitch.";
    $("#conflict").title = c.message ? displayUnits(c.message) : "";
    $("#conflict").classList.remove("hidden");
  }
  function conflictRefusal(data) {
    const m = /refused, the service ends: (.*)$/.exec((data && data.message) || "");
    if (m && !(ui.conflict && ui.conflict.ends)) showConflict({ message: m[1], other: (/\(instance (\S+?)[;)]/.exec(m[1]) || [])[1], ends: true });
  }
  $("#conflict-dismiss").addEventListener("click", () => { ui.conflict = null; $("#conflict").classList.add("hidden"); });

  // a restarted service (its state's seq went back) counts motions and sessions from 1 again
  function serviceRestarted() {
    ui.outcomes.clear(); ui.gotoId = null;
    ui.maneuverEnds.clear(); ui.maneuverShown = null;
    level.forget("");
  }

  async function onConnected() {
    ui.outcomes.clear();   // motion ids are the service run's own: a restarted service counts from 1 again
    ui.maneuverEnds.clear(); ui.maneuverShown = null;   // and maneuver ids
    // what was refused while disconnected is no longer news once connected (a trial: "goto: not connected to the
    // service" stood under the form and in the footer beside "Service: connected")
    for (const r of document.querySelectorAll(".result.err")) {
      if (r.textContent.includes("not connected to the service")) { r.textContent = ""; r.className = "result"; }
    }
    if (ui.wasConnected) log("connected to the service again");
    ui.wasConnected = true;
    level.forget("");
    renderConnection();
    const selections = ui.implementSelections;
    const r = await call("config", {});
    if (r.ok) {
      ui.config = r.data;
      // an implement_selected handled while this answer was on its way is newer than the answer's implement
      if (ui.implementSelections !== selections) ui.config.implement = ui.implementSelected;
      buildGauges(); renderConfig(); renderRanges();
    }
    refreshPresets();
    refreshManeuvers();
    refreshImplements();
  }

  // ------------------------------------------------------------------ login
  async function fetchSession() {
    try {
      const resp = await fetch("/api/session", { headers: { Accept: "application/json" } });
      return resp.ok ? await resp.json() : null;
    } catch (e) { return null; }
  }

  // Ask the server who we are; show the login form or (re)connect the WebSocket.
  async function checkSession(reason) {
    const s = await fetchSession();
    if (s === null) { setTimeout(() => checkSession(reason), link.retryMs); link.retryMs = Math.min(link.retryMs * 2, 4000); return; }
    ui.session = s;
    if (s.login && !s.authenticated) { showLogin(reason); return; }
    document.body.classList.remove("logged-out");
    $("#login").classList.add("hidden");
    renderUser();
    if (!link.ws || link.ws.readyState === WebSocket.CLOSED) link.connect();
  }

  function showLogin(reason) {
    ui.session = { ...(ui.session || {}), authenticated: false, csrf: null, role: null };
    document.body.classList.add("logged-out");
    $("#login").classList.remove("hidden");
    renderUser();
    renderConnection();
    $("#login-result").textContent = reason && reason !== "log in first" ? reason : "";
    $("#login-result").className = "result err";
    $("#login-form").elements.user.focus();
  }

  $("#login-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const f = ev.target;
    let resp, data;
    try {
      resp = await fetch("/api/login", { method: "POST", headers: { "Content-Type": "application/json" },
        body: JSON.stringify({ user: f.elements.user.value.trim(), password: f.elements.password.value }) });
      data = await resp.json();
    } catch (e) { result("#login-result", "login: the service is not reachable", false); return; }
    f.elements.password.value = "";
    if (!resp.ok) { result("#login-result", data.message || `login refused (${resp.status})`, false); return; }
    ui.session = data;
    result("#login-result", "", true);
    await checkSession("");
  });

  $("#logout").addEventListener("click", async () => {
    try {
      await fetch("/api/logout", { method: "POST", headers: { "Content-Type": "application/json",
        "X-CSRF-Token": (ui.session && ui.session.csrf) || "" }, body: "{}" });
    } catch (e) { /* the server forgets the session at its expiry anyway */ }
    jog.releaseAll();
    showLogin("logged out");
  });

  function renderUser() {
    const s = ui.session || {}, u = $("#user"), viewer = s.authenticated && s.role === "viewer";
    u.classList.toggle("hidden", !s.login || !s.authenticated);
    u.textContent = s.authenticated ? `${s.user} · ${s.role}` : "";
    $("#logout").classList.toggle("hidden", !s.login || !s.authenticated);
    document.body.classList.toggle("viewer", Boolean(viewer));
    // a viewer watches and stops: the service refuses motion anyway, the page says so up front
    for (const b of $$(".motion-only")) { b.disabled = Boolean(viewer); b.title = viewer ? `${s.user} is a viewer: watch and STOP only` : (b.dataset.title || ""); }
  }

  // ------------------------------------------------------------------ input ranges (from the service's config)
  function renderRanges() {
    const w = ui.config && ui.config.limits && ui.config.limits.workspace;
    if (!w) return;
    const f = $("#goto-form");
    for (const k of DOFS) {
      const [lo, hi] = w[k], unit = dofUnit(k), c = dofK(k), d = dofDigits(k);
      const range = `${fmt(lo * c, d)} … ${fmt(hi * c, d)}`;
      $(`#range-${k}`).textContent = range;
      const input = f.elements[k];
      input.placeholder = `keep · ${range}`;
      input.title = `${k} in ${unit}, workspace ${range} ${unit}${k === "x" ? " (+ = the driver's left)" : ""}; empty = keep`;
      input.dataset.min = String(lo * c); input.dataset.max = String(hi * c);
    }
    for (const e of $$(".angle-unit")) e.textContent = angleUnit().unit;
  }

  // ------------------------------------------------------------------ gauges (SVG, built once per config)
  function el(parent, name, attrs = {}, text) {
    const e = document.createElementNS(svgNS, name);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
    if (text !== undefined) e.textContent = text;
    parent.appendChild(e);
    return e;
  }

  // A linear bar: value → pixel along the track; `flip` puts the positive end on the left/top.
  function buildBar(svg, dof, vertical) {
    svg.textContent = "";
    const [lo, hi] = ui.config.limits.workspace[dof];
    const pad = 0.15 * (hi - lo), a = Math.min(lo, 0) - pad, b = Math.max(hi, 0) + pad;
    const len = vertical ? 170 : 200, off = vertical ? 15 : 10;
    // vertical: +z up; horizontal: +x (driver's left) on the left
    const pos = (v) => off + (b - Math.max(a, Math.min(b, v))) / (b - a) * len;
    const g = { pos, lo, hi, vertical };
    if (vertical) {
      el(svg, "rect", { class: "track", x: 26, y: off, width: 28, height: len });
      g.fill = el(svg, "rect", { class: "fill", x: 28, width: 24 });
      el(svg, "line", { class: "zero", x1: 20, x2: 60, y1: pos(0), y2: pos(0) });
      for (const v of [lo, hi]) el(svg, "line", { class: "limit", x1: 20, x2: 60, y1: pos(v), y2: pos(v) });
      g.target = el(svg, "path", { class: "target", d: "M0,0 l-9,-6 v12 z" });
      el(svg, "text", { x: 2, y: 10 }, "z");
      el(svg, "text", { x: 62, y: pos(hi) + 4, class: "dim" }, `${fmt(hi * 1000)}`);
      el(svg, "text", { x: 62, y: pos(0) + 4, class: "dim" }, "0");
      el(svg, "text", { x: 62, y: pos(lo) + 4, class: "dim" }, `${fmt(lo * 1000)}`);
      el(svg, "text", { x: 62, y: 196, class: "dim" }, "mm");
    } else {
      el(svg, "rect", { class: "track", x: off, y: 24, width: len, height: 22 });
      g.fill = el(svg, "rect", { class: "fill", y: 26, height: 18 });
      el(svg, "line", { class: "zero", y1: 20, y2: 52, x1: pos(0), x2: pos(0) });
      for (const v of [lo, hi]) el(svg, "line", { class: "limit", y1: 20, y2: 52, x1: pos(v), x2: pos(v) });
      g.target = el(svg, "path", { class: "target", d: "M0,0 l-6,-8 h12 z" });
      el(svg, "text", { x: off, y: 11 }, "x   ◀ left");   // y 11: the 11 px text's top inside the box
      el(svg, "text", { x: off + len, y: 11, "text-anchor": "end" }, "right ▶");
      // unsigned: the side is the label's (+x is the left); the readout says "left/right n mm" too
      el(svg, "text", { x: pos(hi), y: 64, class: "dim", "text-anchor": "middle" }, `${fmtNoNegZero(Math.abs(hi) * 1000)}`);
      el(svg, "text", { x: pos(0), y: 64, class: "dim", "text-anchor": "middle" }, "0");
      el(svg, "text", { x: pos(lo), y: 64, class: "dim", "text-anchor": "middle" }, `${fmtNoNegZero(Math.abs(lo) * 1000)} mm`);
    }
    return g;
  }

  function drawBar(g, v, target) {
    if (!g) return;
    const p0 = g.pos(0), p = g.pos(Number.isFinite(v) ? v : 0);
    const span = g.hi - g.lo, near = Math.min(g.hi - v, v - g.lo) / span;
    g.fill.setAttribute("class", `fill ${near <= 0.005 ? "danger" : near < 0.08 ? "caution" : ""}`);
    if (g.vertical) { g.fill.setAttribute("y", Math.min(p0, p)); g.fill.setAttribute("height", Math.abs(p - p0)); }
    else { g.fill.setAttribute("x", Math.min(p0, p)); g.fill.setAttribute("width", Math.abs(p - p0)); }
    const show = Number.isFinite(target);
    g.target.style.display = show ? "" : "none";
    if (show) g.target.setAttribute("transform", g.vertical ? `translate(24,${g.pos(target)})` : `translate(${g.pos(target)},22)`);
  }

  // A needle dial over ±range (range = 1.3 × the larger limit); 0 points up, a positive angle turns it
  // counter-clockwise: as the pictures beside it turn (the rear view's bar rises to the right with +roll, the side
  // view's mast leans to the front, left, with +pitch; the needles turned the other way, an operator's trial).
  function buildDial(svg, dof) {
    svg.textContent = "";
    const [lo, hi] = ui.config.limits.workspace[dof];
    const range = 1.3 * Math.max(Math.abs(lo), Math.abs(hi), 1e-3);
    const cx = 60, cy = 66, r = 48;
    const ang = (v) => -Math.max(-100, Math.min(100, v / range * 90)) * Math.PI / 180;   // screen: clockwise > 0
    const pt = (v, rr) => [cx + rr * Math.sin(ang(v)), cy - rr * Math.cos(ang(v))];
    // clockwise on the screen from v1 (left of up for v1 > 0) to v0
    const arc = (v0, v1) => { const [x0, y0] = pt(v1, r), [x1, y1] = pt(v0, r); return `M${x0},${y0} A${r},${r} 0 0 1 ${x1},${y1}`; };
    el(svg, "path", { class: "arc", d: arc(-range, range) });
    el(svg, "path", { class: "arc-ok", d: arc(lo, hi) });
    for (const v of [lo, hi]) { const [x0, y0] = pt(v, r - 9), [x1, y1] = pt(v, r + 9); el(svg, "line", { class: "limit", x1: x0, y1: y0, x2: x1, y2: y1 }); }
    const g = { ang, cx, cy, r, lo, hi };
    g.target = el(svg, "line", { class: "target", x1: cx, y1: cy - r + 6, x2: cx, y2: cy - r - 8 });
    g.needle = el(svg, "line", { class: "needle", x1: cx, y1: cy, x2: cx, y2: cy - r + 4 });
    el(svg, "circle", { cx, cy, r: 5, fill: "#e8edf2" });
    el(svg, "text", { x: 2, y: 12 }, dof);
    g.label = el(svg, "text", { x: cx, y: 80, "text-anchor": "middle" }, "—");   // its descenders inside the 84 px box
    return g;
  }

  function drawDial(g, v, target) {
    if (!g) return;
    const deg = (x) => g.ang(x) * 180 / Math.PI;
    g.needle.setAttribute("transform", `rotate(${deg(Number.isFinite(v) ? v : 0)} ${g.cx} ${g.cy})`);
    g.needle.setAttribute("class", `needle ${v <= g.lo + 1e-4 || v >= g.hi - 1e-4 ? "danger" : ""}`);
    const show = Number.isFinite(target);
    g.target.style.display = show ? "" : "none";
    if (show) g.target.setAttribute("transform", `rotate(${deg(target)} ${g.cx} ${g.cy})`);
    g.label.textContent = show_angle(v);
  }

  const gauges = {};
  function buildGauges() {
    gauges.x = buildBar($("#g-x"), "x", false);
    gauges.z = buildBar($("#g-z"), "z", true);
    gauges.roll = buildDial($("#g-roll"), "roll");
    gauges.pitch = buildDial($("#g-pitch"), "pitch");
    const box = $("#actuators");
    box.textContent = "";
    gauges.act = {};
    for (const [n, [lo, hi]] of Object.entries(ui.config.limits.strokes)) {
      const row = document.createElement("div");
      row.className = "act";
      row.id = `act-${n}`;
      if (n === "lift") row.title = `lift: % of the lift-arm stroke, angle θ_E ${show_mrad(lo)} (0 %) … ${show_mrad(hi)} (100 %)`;
      row.innerHTML = `<span class="name">${n}</span><span class="barwrap"><span class="barfill"></span><span class="ref"></span>` +
        `<span class="lo">${showActuator(n, lo)}</span><span class="hi">${showActuator(n, hi)}</span></span><span class="val">—</span>`;
      box.appendChild(row);
      gauges.act[n] = { lo, hi, fill: row.querySelector(".barfill"), ref: row.querySelector(".ref"), val: row.querySelector(".val") };
    }
  }

  // ------------------------------------------------------------------ the hitch picture
  // Rear view (seen from behind, looking forward: +x, the driver's left, on the left; z up) and side
  // view (from the left: the tractor on the left, rearward +y to the right; z up), both drawn from the
  // model's points (tractor frame) at one scale. Each member: [data-member groups, from, to, class].
  const REAR = [
    [["limiter_left"], "C_l", "B_l", "m cyl"], [["limiter_right"], "C_r", "B_r", "m cyl"],
    [["limiter_left"], "B_l", "Bp_l", "m thin"], [["limiter_right"], "B_r", "Bp_r", "m thin"],
    [["lower_link", "lower_link_left"], "L0", "L", "m"], [["lower_link", "lower_link_right"], "R0", "R", "m"],
    [["lift_arm"], "Q_l", "S_l", "m"], [["lift_arm"], "Q_r", "S_r", "m"],
    [["lift_rod_left"], "S_l", "A_l", "m thin"], [["lift_rod_right"], "S_r", "A_r", "m cyl"],
    [["top_link"], "H", "U", "m cyl"],
    [["implement"], "L", "R", "m impl"], [["mast", "implement"], "L", "U", "m impl"], [["mast", "implement"], "R", "U", "m impl"],
  ];
  const SIDE = [
    [["lower_link", "lower_link_right"], "R0", "R", "m thin"], [["lift_rod_right"], "S_r", "A_r", "m cyl"],
    [["limiter_left"], "C_l", "B_l", "m thin"],
    [["lower_link", "lower_link_left"], "L0", "L", "m"], [["lift_arm"], "Q_l", "S_l", "m"],
    [["lift_rod_left"], "S_l", "A_l", "m thin"], [["top_link"], "H", "U", "m cyl"],
    [["mast", "implement"], "T", "U", "m impl"],
  ];
  // px kept free above (titles; the "Control limited" box, two lines, covers them) and below the ground line (labels:
  // the rear view's heights on a line of their own above "◀ left … right ▶" — on one line "↑624 mm" ran into
  // "right ▶" on a phone)
  const VIEW_TOP = 32, VIEW_BOTTOM = 24;

  function onTerminal(t) { hv.info = t; hv.rear = hv.side = null; hv.drawn = null; ui.drawn = false; requestAnimationFrame(draw); }
  function onView(v) { hv.msg = v; ui.drawn = false; requestAnimationFrame(draw); }

  // one scale for both views, fixed from the first measured points (the picture does not jump)
  function viewScale(p, info, W, H) {
    const ws = info.workspace || { x: [0, 0], z: [0, 0] };
    const names = Object.keys(p), g = info.ground_z;
    const zs = names.map((n) => p[n][2]), xs = names.map((n) => Math.abs(p[n][0])), ys = names.map((n) => p[n][1]);
    const zTop = Math.max(...zs) + Math.max(0, ws.z[1] - p.T[2]) + 0.06;
    const xr = Math.max(...xs) + Math.max(Math.abs(ws.x[0]), Math.abs(ws.x[1])) + 0.08;
    const y0 = Math.min(...ys) - 0.45, y1 = Math.max(...ys) + 0.12;
    const s = Math.min((H - VIEW_BOTTOM - VIEW_TOP) / (zTop - g), (W - 16) / (2 * xr), (W - 8) / (y1 - y0));
    return { s, g, y0, y1, W, H, ground: H - VIEW_BOTTOM };
  }

  function buildView(svg, members, sc, rear) {
    svg.textContent = "";
    const VIEW_W = sc.W;
    svg.setAttribute("viewBox", `0 0 ${sc.W} ${sc.H}`);   // one unit = one CSS pixel: text stays 10 px
    const info = hv.info, v = { svg, sc, rear, lines: [], ghost: [] };
    // side view: centred on the hitch's own extent
    const ySpan = (sc.y1 - sc.y0) * sc.s, yOff = Math.max(4, (VIEW_W - ySpan) / 2);
    v.px = rear ? (x) => VIEW_W / 2 - x * sc.s : (y) => yOff + (y - sc.y0) * sc.s;
    v.py = (z) => sc.ground - (z - sc.g) * sc.s;
    v.at = (pt) => [v.px(rear ? pt[0] : pt[1]), v.py(pt[2])];
    const w = info.rear_wheel;
    if (!rear && w) el(svg, "circle", { class: "wheel", cx: v.px(w.y), cy: v.py(w.z), r: w.radius * sc.s });
    el(svg, "line", { class: "ground-line", x1: 0, x2: VIEW_W, y1: v.py(sc.g), y2: v.py(sc.g) });
    v.wsBox = el(svg, "rect", { class: "ws", "data-ws": rear ? "x z" : "z" });
    v.wsAngle = [el(svg, "line", { class: "ws", "data-ws": rear ? "roll" : "pitch" }), el(svg, "line", { class: "ws", "data-ws": rear ? "roll" : "pitch" })];
    for (const [groups, a, b, cls] of members) {
      v.lines.push({ groups, a, b, cls, e: el(svg, "line", { class: cls, "data-member": groups[0] }) });
    }
    // the target (the service's reference actuators), dashed over the measured members
    const gg = el(svg, "g", { class: "ghost" });
    for (const [, a, b, cls] of members) v.ghost.push({ a, b, e: el(gg, "line", { class: cls }) });
    v.ghostGroup = gg;
    v.fixed = ["L0", "R0", "Q_l", "Q_r", "H", "C_l", "C_r"].map((n) => ({ n, e: el(svg, "rect", { class: "fixed", width: 4, height: 4 }) }));
    v.balls = (rear ? ["L", "R"] : ["L"]).map((n) => ({ n, e: el(svg, "circle", { class: "ball", r: 3.5, "data-member": "implement", "data-point": n }) }));
    const bottom = sc.H - 2;   // labels under the ground line: nothing is drawn there
    // a narrow side view (a phone): the short title, the "Angles" button covers its right end ("◀ front … rear ▶"
    // under it say the side)
    el(svg, "text", { class: "title", x: 4, y: 11 }, rear ? "Rear view" : VIEW_W < 300 ? "Side view" : "Side view, from the left");
    if (rear) {
      el(svg, "text", { class: "title", x: 4, y: bottom }, "◀ left");
      el(svg, "text", { class: "title", x: VIEW_W - 4, y: bottom, "text-anchor": "end" }, "right ▶");
      v.hL = el(svg, "text", { class: "hgt", "text-anchor": "end", y: bottom - 11 });
      v.hR = el(svg, "text", { class: "hgt", "text-anchor": "start", y: bottom - 11 });
      v.note = el(svg, "text", { class: "title", x: VIEW_W - 4, y: 11, "text-anchor": "end" }, "");
    } else {
      el(svg, "text", { class: "title", x: 4, y: bottom }, "◀ front");
      el(svg, "text", { class: "title", x: VIEW_W - 4, y: bottom, "text-anchor": "end" }, "rear ▶");
      v.hT = el(svg, "text", { class: "hgt", "text-anchor": "start" });
      v.lift = el(svg, "text", { class: "hgt", "text-anchor": "middle" });
    }
    return v;
  }

  // a drawn text's width [px] (one unit = one CSS pixel in the views); 0 before it is laid out
  const textLength = (t) => { try { return t.getComputedTextLength(); } catch (e) { return 0; } };

  function setLine(e, p0, p1) {
    e.setAttribute("x1", p0[0].toFixed(1)); e.setAttribute("y1", p0[1].toFixed(1));
    e.setAttribute("x2", p1[0].toFixed(1)); e.setAttribute("y2", p1[1].toFixed(1));
  }

  function drawView(v, meas, goal, moving, lit, limitedCodes) {
    const p = meas.points, info = hv.info, ws = info.workspace;
    for (const l of v.lines) {
      setLine(l.e, v.at(p[l.a]), v.at(p[l.b]));
      l.e.setAttribute("class", `${l.cls}${l.groups.some((g) => lit.has(g)) ? " hl" : ""}`);
    }
    // the ghost: where the running motion ends (the plan's final actuators through the model)
    const showGhost = Boolean(moving && goal);
    v.ghostGroup.style.display = showGhost ? "" : "none";
    if (showGhost) for (const l of v.ghost) setLine(l.e, v.at(goal.points[l.a]), v.at(goal.points[l.b]));
    for (const f of v.fixed) { const [x, y] = v.at(p[f.n]); f.e.setAttribute("x", (x - 2).toFixed(1)); f.e.setAttribute("y", (y - 2).toFixed(1)); }
    for (const b of v.balls) {
      const [x, y] = v.at(p[b.n]); b.e.setAttribute("cx", x.toFixed(1)); b.e.setAttribute("cy", y.toFixed(1));
      b.e.setAttribute("class", `ball${lit.has("implement") ? " hl" : ""}`);
    }
    const hit = (dofs) => limitedCodes.some((c) => dofs.some((d) => c.startsWith(`workspace:${d}:`)));
    if (ws) {
      // the workspace box of the tool point T (x, z in the rear view; z in the side view at T's y)
      const T = p.T;
      const x0 = v.rear ? v.px(ws.x[0]) : v.px(T[1]) - 3, x1 = v.rear ? v.px(ws.x[1]) : v.px(T[1]) + 3;
      v.wsBox.setAttribute("x", Math.min(x0, x1).toFixed(1)); v.wsBox.setAttribute("width", Math.abs(x1 - x0).toFixed(1));
      v.wsBox.setAttribute("y", v.py(ws.z[1]).toFixed(1)); v.wsBox.setAttribute("height", (v.py(ws.z[0]) - v.py(ws.z[1])).toFixed(1));
      v.wsBox.setAttribute("class", `ws${hit(v.rear ? ["x", "z"] : ["z"]) ? " hl" : ""}`);
      // the roll limits (the lower-hitch bar's allowed tilt) or the pitch limits (the mast's) through T
      const lims = v.rear ? ws.roll : ws.pitch, [tx, ty] = v.at(T);
      const half = v.rear ? Math.hypot(p.L[0] - p.R[0], p.L[2] - p.R[2]) / 2 + 0.2 : Math.hypot(p.U[1] - T[1], p.U[2] - T[2]) + 0.12;
      lims.forEach((a, i) => {
        // rear: the bar L−R ∝ (cos a, −sin a) in (x, z), x drawn to the left; side: the mast ∝ (−sin a, cos a) in (y, z)
        const [dx, dy] = v.rear ? [-Math.cos(a), Math.sin(a)] : [-Math.sin(a), -Math.cos(a)];
        const k = half * v.sc.s;
        setLine(v.wsAngle[i], v.rear ? [tx - dx * k, ty - dy * k] : [tx, ty], [tx + dx * k, ty + dy * k]);
        v.wsAngle[i].setAttribute("class", `ws${hit([v.rear ? "roll" : "pitch"]) ? " hl" : ""}`);
      });
    }
    const ag = meas.above_ground || {};
    if (v.rear) {
      // the lower hitch points' heights above the ground, under each point
      const [lx] = v.at(p.L), [rx] = v.at(p.R);
      // under each lower hitch point, outwards from the middle, kept inside the view
      v.hL.textContent = `↑${fmt(1000 * ag.L, 0)} mm`; v.hR.textContent = `↑${fmt(1000 * ag.R, 0)} mm`;
      v.hL.setAttribute("x", Math.max(2 + textLength(v.hL), lx).toFixed(1));
      v.hR.setAttribute("x", Math.min(v.sc.W - 2 - textLength(v.hR), rx).toFixed(1));
    } else {
      const [tx, ty] = v.at(p.T), [sx, sy] = v.at(p.S_l);
      v.hT.textContent = `${fmt(1000 * ag.T, 0)} mm`;
      // right of the tool point, or left of it where the view ends (it was cut off at the right edge)
      const right = tx + 8 + textLength(v.hT) <= v.sc.W - 2;
      v.hT.setAttribute("text-anchor", right ? "start" : "end");
      v.hT.setAttribute("x", (right ? tx + 8 : tx - 8).toFixed(1)); v.hT.setAttribute("y", (ty + 4).toFixed(1));
      v.lift.textContent = `lift ${fmt(100 * meas.lift_fraction, 0)} %`;
      const half = textLength(v.lift) / 2;
      v.lift.setAttribute("x", Math.max(2 + half, Math.min(v.sc.W - 2 - half, sx)).toFixed(1));
      v.lift.setAttribute("y", (sy - 7).toFixed(1));
    }
  }

  function drawViews(s) {
    const info = hv.info, msg = hv.msg;
    if (!info || !msg || !msg.measured) {
      $("#r-ground").textContent = "above ground: —";
      if (hv.rear && hv.rear.note) hv.rear.note.textContent = info ? "no measured pose" : "waiting for the model…";
      return;
    }
    if (hv.drawn === msg && hv.drawnMoving === s.moving) return;
    hv.drawn = msg; hv.drawnMoving = s.moving;
    if (!hv.rear) {
      const box = $("#v-rear").getBoundingClientRect();
      if (box.width < 40 || box.height < 40) return;   // not laid out (hidden): try again next frame
      const sc = viewScale(msg.measured.points, info, Math.round(box.width), Math.round(box.height));
      hv.rear = buildView($("#v-rear"), REAR, sc, true);
      hv.side = buildView($("#v-side"), SIDE, sc, false);
    }
    const lit = new Set(msg.highlight || []), codes = (msg.limited || []).map((e) => e.code);
    for (const v of [hv.rear, hv.side]) drawView(v, msg.measured, msg.goal, s.moving, lit, codes);
    const ag = msg.measured.above_ground;
    $("#r-ground").textContent = `above ground: L ${fmt(1000 * ag.L, 0)} · R ${fmt(1000 * ag.R, 0)} mm`;
    hv.rear.note.textContent = lit.size ? "red: what limits" : s.moving && msg.goal ? "dashed: where it ends" : "";
  }

  // ------------------------------------------------------------------ angle unit (a setting of this browser)
  function renderAngleUnit() {
    $("#angle-unit").textContent = `Angles: ${angleUnit().unit}`;
    $("#angle-unit").setAttribute("aria-label", `angle unit: ${angleUnit().unit === "deg" ? "degrees" : "milliradians"} (click to change)`);
    for (const e of $$(".angle-unit")) e.textContent = angleUnit().unit;
  }
  $("#angle-unit").addEventListener("click", () => {
    units.angle = units.angle === "mrad" ? "deg" : "mrad";
    try { localStorage.setItem(ANGLE_KEY, units.angle); } catch (e) { /* not saved: this page only */ }
    renderAngleUnit();
    if (ui.config) { renderRanges(); renderConfig(); }
    for (const k of ["roll", "pitch"]) $(`#goto-form`).elements[k].value = "";   // typed in the old unit
    refreshPresets();
    level.render();
    ui.drawn = false; requestAnimationFrame(draw);
  });
  renderAngleUnit();
  window.addEventListener("resize", () => { hv.rear = hv.side = null; hv.drawn = null; ui.drawn = false; requestAnimationFrame(draw); });

  // ------------------------------------------------------------------ state → screen
  function onState(s) {
    if (ui.state && Number.isFinite(s.seq) && Number.isFinite(ui.state.seq) && s.seq < ui.state.seq) serviceRestarted();
    ui.state = s;
    ui.lastStateMs = performance.now();
    ui.drawn = false;
    requestAnimationFrame(draw);
  }

  function draw() {
    if (ui.drawn || !ui.state) return;
    ui.drawn = true;
    ui.frames += 1;
    const s = ui.state, pose = s.pose || {}, ref = (s.reference && s.reference.pose) || {};
    if (ui.config) {
      drawBar(gauges.x, pose.x, ref.x);
      drawBar(gauges.z, pose.z, ref.z);
      drawDial(gauges.roll, pose.roll, ref.roll);
      drawDial(gauges.pitch, pose.pitch, ref.pitch);
      drawActuators(s);
    }
    for (const k of DOFS) $(`#r-${k}`).textContent = k === "x" ? show_x(pose.x) : showDof(k, pose[k]);
    drawLimited(s.limited || {});
    drawViews(s);
    level.draw(s);
    drawMargins(s);
    drawModeAndMotion(s);
    renderConnection();
  }

  function drawActuators(s) {
    const q = s.actuators || {}, qr = (s.reference && s.reference.actuators) || {};
    for (const [n, g] of Object.entries(gauges.act || {})) {
      const v = q[n], frac = (v - g.lo) / (g.hi - g.lo);
      const f = Math.max(0, Math.min(1, Number.isFinite(frac) ? frac : 0));
      g.fill.style.width = `${(100 * f).toFixed(1)}%`;
      const edge = Math.min(f, 1 - f);
      g.fill.className = `barfill ${edge <= 0.01 ? "danger" : edge < 0.05 ? "caution" : ""}`;
      const rf = (qr[n] - g.lo) / (g.hi - g.lo);
      g.ref.style.display = Number.isFinite(rf) ? "" : "none";
      if (Number.isFinite(rf)) g.ref.style.left = `calc(${(100 * Math.max(0, Math.min(1, rf))).toFixed(1)}% - 1px)`;
      g.val.textContent = showActuator(n, v);
      if (n === "lift") g.val.title = `lift-arm angle ${show_mrad(v)}`;
    }
  }

  // One state.limited entry in the operator's words: the server's (with the guard's numbers) when its
  // latest view has the same entry, else the terminal's table, else as it came. Returns [words, code].
  // a measure may have spaces: the implement's own limits ("speed: implement upper height limit would be 0.2464 m …"
  // was shown as it came, the guard's raw sentence in metres: a trial)
  const GUARD_RE = /^(hard|caution|speed):\s*(\S.*?) would be/;
  // the implement's limits: the server words them in SI (m, m/s; bridge/web/wording.py), the page shows mm
  const IMPLEMENT_LIMIT = /^implement .* limit$/;
  function limitedEntryWords(k, v) {
    const name = String(v), info = hv.info, g = GUARD_RE.exec(name), code = g ? g[2] : name;
    const fromView = ((hv.msg && hv.msg.limited) || []).find((e) => e.key === k && e.code === code);
    if (fromView) return [IMPLEMENT_LIMIT.test(code) ? displayUnits(fromView.words) : fromView.words, code];
    const w = info && info.words && info.words[code];
    const measure = g && hv.info && hv.info.words && ["front_axle_load", "ssm", "lsm", "esm"].includes(code);
    if (w) return [measure ? `${w}: ${g[1] === "hard" ? "refused" : "slowed"}` : w, code];
    return [displayUnits(`${k}: ${name}`), ""];
  }
  window.hitchTerminal = { ...(window.hitchTerminal || {}), limitedEntryWords, inWords };

  function drawLimited(limited) {
    const entries = Object.entries(limited);
    const box = $("#limited");
    box.classList.toggle("hidden", entries.length === 0);
    if (!entries.length) return;
    const key = JSON.stringify(entries) + (hv.msg ? hv.msg.seq : "");
    if (box.dataset.key === key) return;
    box.dataset.key = key;
    box.textContent = "Control limited: ";
    const all = [];
    entries.forEach(([k, v], i) => {
      const [words, code] = limitedEntryWords(k, v);
      if (i) box.append("; ");
      box.append(words);
      if (code) { const c = document.createElement("small"); c.className = "code"; c.textContent = ` [${code}]`; box.append(c); }
      all.push(code ? `${words} [${code}]` : words);
    });
    box.title = `Control limited: ${all.join("; ")}`;   // the whole text, also when the box cuts it short
  }

  function setLevel(row, level) { row.classList.remove("ok", "caution", "danger"); if (level) row.classList.add(level); }

  function drawMargins(s) {
    const km = s.kinematic_margin, row = $("#m-kin");
    if (km) {
      const t = km.time_s;
      row.querySelector(".v").textContent = t === null || t === undefined ? "∞" : `${fmt(t, 2)} s`;
      const w = km.limit && hv.info && hv.info.words && hv.info.words[km.limit];
      // "to the height limit (top)", not "to height limit reached (top)": the words say a limit is reached
      row.querySelector(".n").textContent = km.limit ? `to ${(w || km.limit).replace(/ reached\b/, "")}` : "at rest";
      row.title = km.limit ? `time to the nearest limit at the current speed: ${w || ""} [${km.limit}]` : "at rest: no limit ahead";
      setLevel(row, t === null || t === undefined || t > KIN_CAUTION_S ? "ok" : t > KIN_DANGER_S ? "caution" : "danger");
    } else { row.querySelector(".v").textContent = "—"; setLevel(row, ""); }
    const st = s.stability;
    const levels = {};
    for (const v of (st && st.violations) || []) levels[v.measure] = v.level === "hard" ? "danger" : "caution";
    // units and the guard's minimum next to each value; the front axle as a share of the empty tractor's
    // weight (the rule's basis: the steering needs 20 %) when the terminal knows the weights
    const th = (hv.info && hv.info.thresholds) || null, factor = hv.info && hv.info.weight_factor;
    const min = (m, k, unit, d) => th ? `minimum ${fmt(th[m][0] * k, d)} ${unit}` : "";
    // [value, note, the sentence in words (the row's tooltip)]
    const rows = st ? {
      ssm: [`${fmt(st.ssm, 2)} m`, min("ssm", 1, "m", 2), "side stability margin"],
      lsm: [`${fmt(st.lsm, 2)} m`, min("lsm", 1, "m", 2), "fore-aft stability margin"],
      esm: [`${fmt(st.esm / 1000, 1)} kJ`, min("esm", 0.001, "kJ", 1), "energy to tip over"],
      front_axle_load: factor
        ? [`${fmt(100 * st.front_axle_share * factor, 0)} %`, `of the tractor's weight${th ? ` (minimum ${fmt(100 * th.front_axle_fraction[0], 0)} %)` : ""}`, "front axle load"]
        : [`${fmt(100 * st.front_axle_share, 1)} %`, "of the total weight", "front axle load"],
    } : {};
    for (const m of ["ssm", "lsm", "esm", "front_axle_load"]) {
      const r = $(`#m-${m}`);
      r.querySelector(".v").textContent = st ? rows[m][0] : "—";
      if (st) {
        const [v, n, what] = rows[m];
        r.querySelector(".n").textContent = n;
        r.title = m === "front_axle_load" ? `${what} ${v} ${n}` : `${what} ${v}${n ? ` (${n})` : ""}`;
      }
      setLevel(r, st ? (levels[m] || "ok") : "");
    }
  }

  function drawModeAndMotion(s) {
    for (const b of $$("#modes button")) b.classList.toggle("active", b.dataset.mode === s.mode);
    if (ui.mode !== s.mode) { ui.mode = s.mode; renderHelp(); }
    const m = $("#motion");
    m.textContent = s.moving ? `Moving: ${s.motion || "motion"} #${s.motion_id}` : "Idle";
    m.className = `pill ${s.moving ? "warn" : ""}`;
    drawManeuver(s.maneuver);
    actions.draw(s);
    const e = s.ecu || {}, ecu = $("#ecu"), faults = e.faults || [];
    const activity = ecuActivity(s);
    if (!e.online) { ecu.textContent = "ECU: offline"; ecu.className = "pill bad"; }
    else if (faults.length) { ecu.textContent = `ECU fault: ${faults.join(", ")} · ${activity}`; ecu.className = "pill bad"; }
    else { ecu.textContent = `ECU: online · ${activity}`; ecu.className = "pill good"; }
    ecu.dataset.activity = activity;
    // offline: what its valves do is not known here (the ECU zeroes them without fresh references)
    const doing = e.online ? activity : "offline, its valves not known here (without fresh references it zeroes them)";
    ecu.title = [`Cylinder ECU: ${doing}`, ...(e.fault_reasons || [])].join("\n");
    // only latched faults wait for an acknowledgement (self-clearing ones go once the data is fresh again)
    $("#faults-ack").classList.toggle("hidden", (e.ack_required || []).length === 0);
  }

  // Valve activity from what the state carries: the ECU drives its valves towards the reference
  // (the reference moves, or the measured strokes are away from it); otherwise it holds. With
  // the watchdog expired or the controllers off the valves are at zero whatever the reference.
  function ecuActivity(s) {
    const e = s.ecu || {};
    if (e.controllers_on === false) return "valves off";
    // the watchdog bit is also set before the first reference; while the service moves it means
    // the references do not arrive and the ECU has zeroed its valves
    if (e.watchdog) return s.moving ? "holding (watchdog)" : "holding";
    const ref = s.reference && s.reference.actuators, q = s.actuators || {}, v = s.velocity || {};
    if (!ref) return "holding";
    if (DOFS.some((k) => Math.abs(v[k] || 0) > REF_MOVING)) return "driving";
    const strokes = (ui.config && ui.config.limits && ui.config.limits.strokes) || {};
    for (const [n, [lo, hi]] of Object.entries(strokes)) {
      if (Number.isFinite(ref[n]) && Number.isFinite(q[n]) && Math.abs(ref[n] - q[n]) > ECU_HOLD_FRACTION * (hi - lo)) return "driving";
    }
    return "holding";
  }

  $("#faults-ack").addEventListener("click", async () => {
    const b = $("#faults-ack");
    b.disabled = true;
    const r = await call("faults/ack", {});
    b.disabled = document.body.classList.contains("viewer");   // operators only (a viewer's is refused)
    if (r.ok) {
      const left = r.data.faults || [];
      log(`faults acknowledged: ${(r.data.acknowledged || []).join(", ") || "none latched"}` +
        (left.length ? `; still present: ${left.join(", ")}` : ""), left.length > 0);
    }
  });

  function renderConnection() {
    const c = $("#conn"), banner = $("#banner");
    const age = performance.now() - ui.lastStateMs;
    let text, cls, alert = "";
    if (document.body.classList.contains("logged-out")) {
      text = "Service: log in"; cls = "warn";   // not connected on purpose: no alarm, nothing is shown
    } else if (!ui.connected) {
      text = "Service: disconnected"; cls = "bad";
      alert = `Service not reachable: ${ui.closedReason || "connecting"} — no live data; retrying…`;
    } else if (!ui.state || age > STATE_STALE_MS) {
      text = "Service: no state"; cls = "bad"; alert = "The service sends no state: the values shown are not live.";
    } else { text = ui.rate > 0 ? `Service: connected · ${fmt(ui.rate)} Hz` : "Service: connected"; cls = "good"; }
    // "Service: " and the rate in spans of their own: a phone hides them (the pill said "Service: c…" next to
    // the running motion); the text stays whole for everything else
    if (c.textContent !== text) {
      const m = /^(Service: )(.*?)( · \d+ Hz)?$/.exec(text);
      c.textContent = "";
      if (m) {
        const k = document.createElement("span"); k.className = "k"; k.textContent = m[1];
        c.append(k, m[2]);
        if (m[3]) { const hz = document.createElement("span"); hz.className = "hz"; hz.textContent = m[3]; c.append(hz); }
      } else c.textContent = text;
    }
    c.title = `WebSocket to the hitch service: ${text.replace(/^Service: /, "")}`;
    c.className = `pill ${cls}`;
    // the service is live but the ECU's measurement is old (the ECU stopped reporting): the gauges show the
    // last values it sent, greyed like a service that is down, and the banner says how old they are
    const ecuOld = !alert && ui.state ? ecuStale(ui.state) : "";
    banner.textContent = alert || ecuOld;
    banner.classList.toggle("hidden", !(alert || ecuOld));
    document.body.classList.toggle("stale", Boolean(alert || ecuOld));
    document.body.classList.toggle("ecu-stale", Boolean(ecuOld));
    if (alert) {
      $("#motion").textContent = "Motion: unknown"; $("#motion").className = "pill";
      if (!ui.connected) { $("#ecu").textContent = "ECU: unknown"; $("#ecu").className = "pill bad"; }
    }
  }

  // The ECU's measurement age from the state (`ecu.measurement_age_s`, [s]): older than the service's limit
  // (config `stale_timeout_s`, 0.2 s by default) or none at all → the gauges are not live. Returns the banner's
  // sentence, or "" while the measurement is fresh.
  function ecuStale(s) {
    const e = s.ecu;
    if (!e) return "";
    const cfg = ui.config || {};
    const lim = [cfg.stale_timeout_s, cfg.can && cfg.can.stale_timeout_s].find((v) => Number.isFinite(v) && v > 0) || ECU_STALE_S;
    const age = e.measurement_age_s;
    if (age === null || age === undefined) {
      return e.online === false ? "No measurement from the cylinder ECU: the gauges show no live values." : "";
    }
    if (!Number.isFinite(age) || age <= lim) return "";
    return `The cylinder ECU stopped reporting: its measurement is ${fmt(age, 1)} s old (limit ${fmt(lim, 1)} s) — the gauges show the last values, not live.`;
  }

  // frame-rate meter (what the operator sees refreshing) and the staleness watchdog
  setInterval(() => {
    const now = performance.now();
    ui.rate = ui.frames / ((now - (ui.rateSince || now - 1000)) / 1000);
    ui.frames = 0; ui.rateSince = now;
    document.body.dataset.fps = ui.rate.toFixed(1);
    renderConnection();
  }, 1000);

  // ------------------------------------------------------------------ events
  function onEvent(e) {
    const name = e.event || "event";
    if (name === "prefix_conflict") {
      showConflict(e);
      log(`prefix conflict: another service (instance ${e.other || "?"}) serves this prefix: ` +
        (e.ends ? "this service ends itself" : "the other one ends itself"), true);
      return;
    }
    if (name === "last_work_recorded") {   // where a return goes: a raise from the cab's switch or another client
      const imp = actions.implements.find((i) => i.name === e.implement);
      if (imp && e.last_work) { imp.last_work = e.last_work; actions.drawRecord(); }
      refreshImplements();   // asked after the record: an older list's answer still on its way is not drawn over it
      return;   // not logged: the raise's own events say what happened
    }
    let text = name.replace(/_/g, " ");
    if (e.motion_id !== undefined) text += ` #${e.motion_id}`;
    if (e.kind) text += ` (${e.kind})`;
    // what changed, named: another page's mode change or implement choice read "mode changed" / "implement
    // selected" alone (a trial: the operator could not tell to which)
    if (name === "mode_changed" && e.mode) {
      text += `: ${MODE_NAMES[e.mode] || e.mode}` + (e.previous ? ` (was ${MODE_NAMES[e.previous] || e.previous})` : "");
    }
    if (name === "implement_selected") text += `: ${e.implement && e.implement !== "default" ? e.implement : "none (the hitch alone)"}`;
    if (name === "hitch_switch" && e.command) text += `: ${e.command}`;
    if (Array.isArray(e.cleared)) text += `: ${e.cleared.join(", ")}` + (e.by ? ` (${e.by})` : "");
    if (e.reason) text += `: ${e.reason}`;
    if (e.message) text += `: ${e.message}`;
    // which limits: {key: limit name} in the words of the "Control limited" box ("limit reached #18" alone
    // named none: an operator's trial)
    if (name === "limit_reached" && e.limits && typeof e.limits === "object" && Object.keys(e.limits).length) {
      text += ": " + Object.entries(e.limits).map(([k, v]) => {
        const [words, code] = limitedEntryWords(k, v);
        return code ? `${words} [${code}]` : words;
      }).join("; ");
    }
    if (e.maneuver) text = `maneuver ${e.maneuver}: ${name.replace("maneuver_", "")}` + (e.step !== undefined ? ` step ${e.step + 1}` : "") + (e.reason ? ` (${e.reason}: ${e.message || ""})` : "");
    log(text, /abort|fault$|limit/.test(name));
    if (name === "maneuver_started" && e.steps) ui.maneuverSteps[e.maneuver] = e.steps;
    if (e.motion_id !== undefined && /^motion_(finished|aborted)$|^limit_reached$|^fault$/.test(name)) {
      const outcome = [name === "motion_finished" ? `motion #${e.motion_id} finished` : text, name === "motion_finished"];
      ui.outcomes.set(e.motion_id, outcome);   // kept for a goto whose reply is still on its way
      if (ui.outcomes.size > 50) ui.outcomes.delete(ui.outcomes.keys().next().value);
      if (e.motion_id === ui.gotoId) { result("#goto-result", ...outcome); ui.gotoId = null; }
      if (name === "motion_finished" || name === "motion_aborted") actions.motionEnded(e.motion_id, ...outcome);
    }
    level.onEvent(e);
    if (name === "implement_selected") {
      refreshImplements(); refreshPresets();   // the presets are the implement's
      // Help's "implement" (it kept the connect-time one); counted for a config answer still on its way
      ui.implementSelections += 1; ui.implementSelected = e.implement || null;
      if (ui.config) { ui.config.implement = ui.implementSelected; renderConfig(); }
    }
    if (name === "maneuver_finished" || name === "maneuver_aborted") {
      const ended = [name === "maneuver_finished" ? `${e.maneuver} finished in ${fmt(e.elapsed, 1)} s`
        : `${e.maneuver} aborted: ${e.reason} — ${e.message || ""}`, name === "maneuver_finished"];
      ui.maneuverEnds.set(e.maneuver_id, ended);
      if (ui.maneuverEnds.size > 50) ui.maneuverEnds.delete(ui.maneuverEnds.keys().next().value);
      // the end of a maneuver older than the one shown running (a Run replaces the running maneuver, whose
      // "replaced by another maneuver" may come after the new one's reply) does not cover it
      const older = Number.isInteger(e.maneuver_id) && Number.isInteger(ui.maneuverShown) && e.maneuver_id < ui.maneuverShown;
      if (!older) {
        $("#maneuver-result").textContent = ended[0];
        $("#maneuver-result").className = `result ${ended[1] ? "ok" : "err"}`;
      }
    }
  }

  // ------------------------------------------------------------------ STOP and modes
  async function stop() {
    jog.releaseAll();
    level.halt("STOP", false, true);
    const r = await link.request("stop", {});
    if (r.ok) { log("STOP: motion stopped"); return; }
    // the WebSocket is down: try the plain HTTP API of the same server
    try {
      const resp = await fetch("/api/stop", { method: "POST", headers: { "Content-Type": "application/json" }, body: "{}" });
      log(resp.ok ? "STOP: motion stopped (HTTP)" : `STOP refused: ${(await resp.json()).message}`, !resp.ok);
    } catch (e) { log("STOP could not reach the service", true); }
  }
  $("#stop").addEventListener("pointerdown", (ev) => { ev.preventDefault(); stop(); });
  $("#stop").addEventListener("click", (ev) => { if (ev.detail === 0) stop(); });   // keyboard activation

  function confirmDialog(title, text, okLabel = "Switch") {
    return new Promise((resolve) => {
      $("#confirm-title").textContent = title;
      $("#confirm-text").textContent = text;
      $("#confirm-ok").textContent = okLabel;
      $("#confirm").classList.remove("hidden");
      const done = (v) => { $("#confirm").classList.add("hidden"); $("#confirm-ok").onclick = $("#confirm-cancel").onclick = null; resolve(v); };
      $("#confirm-ok").onclick = () => done(true);
      $("#confirm-cancel").onclick = () => done(false);
    });
  }

  for (const b of $$("#modes button")) {
    b.addEventListener("click", async () => {
      const mode = b.dataset.mode;
      if (ui.state && ui.state.mode === mode) return;
      if (mode === "manual" || mode === "attach") {
        const ok = await confirmDialog(`Switch to ${MODE_NAMES[mode]} mode?`, HELP[mode].join(" "));
        if (!ok) return;
      }
      const r = await call("mode", { mode });
      if (r.ok) log(`mode: ${MODE_NAMES[r.data.mode] || r.data.mode}`);
    });
  }

  function renderHelp() {
    const mode = ui.mode || "main";
    $("#help-title").textContent = `${MODE_NAMES[mode] || "Main"} mode`;
    $("#help-text").innerHTML = "";
    for (const p of [...(HELP[mode] || []), ...HELP.main]) {
      const e = document.createElement("p"); e.textContent = p; $("#help-text").appendChild(e);
    }
  }

  function renderConfig() {
    const c = ui.config, dl = $("#config");
    dl.textContent = "";
    const w = c.limits.workspace;
    const rows = [["profile", c.profile], ["category", c.category], ["implement", c.implement || "none"],
      ["control rate", `${c.control_rate} Hz`], ["state rate", `${c.state_rate} Hz`],
      ["workspace x", `${fmt(w.x[0] * 1000)} … ${fmt(w.x[1] * 1000)} mm`], ["workspace z", `${fmt(w.z[0] * 1000)} … ${fmt(w.z[1] * 1000)} mm`],
      ["roll", `${fmt(w.roll[0] * dofK("roll"), dofDigits("roll"))} … ${fmt(w.roll[1] * dofK("roll"), dofDigits("roll"))} ${dofUnit("roll")}`],
      ["pitch", `${fmt(w.pitch[0] * dofK("pitch"), dofDigits("pitch"))} … ${fmt(w.pitch[1] * dofK("pitch"), dofDigits("pitch"))} ${dofUnit("pitch")}`],
      ["user", ui.hello && ui.hello.login ? `${ui.hello.user} (${ui.hello.role})` : (ui.hello && ui.hello.user) || "(no access control)"]];
    for (const [k, v] of rows) {
      const dt = document.createElement("dt"), dd = document.createElement("dd");
      dt.textContent = k; dd.textContent = v; dl.append(dt, dd);
    }
  }

  // ------------------------------------------------------------------ jog (dead-man)
  const jog = {
    held: new Map(), timer: null,
    rates() {
      const speed = Number($("#jog-speed").value) / 100, v = { x: 0, z: 0, roll: 0, pitch: 0 };
      for (const { dof, sign } of this.held.values()) { const m = jogMax(dof); v[dof] = Math.max(-m, Math.min(m, v[dof] + sign * m * speed)); }
      return { vx: v.x, vz: v.z, vroll: v.roll, vpitch: v.pitch, ttl_ms: JOG_TTL_MS };
    },
    send() {
      link.request("jog", this.rates()).then((r) => {
        if (r.ok) { this.saidDisconnected = false; return; }
        // not connected: said once per press (a jog was dropped silently while goto said so: a trial)
        if (r.data.error === "disconnected") { if (!this.saidDisconnected) log(r.data.message || "jog: not connected to the service", true); this.saidDisconnected = true; return; }
        // refused (another operator's jog, a stop that ended this one, the mode, a fault): said once and the
        // buttons released — press again to jog (it went on sending 12 refusals a second: a review)
        if (!this.saidRefused) log(r.data.message || "jog refused", true);
        this.saidRefused = true;
        this.releaseAll();
      });
    },
    press(source, dof, sign) {
      if (this.held.has(source) || document.body.classList.contains("viewer")) return;
      if (this.held.size === 0) { this.saidDisconnected = false; this.saidRefused = false; }
      this.held.set(source, { dof, sign });
      this.mark();
      this.send();
      if (!this.timer) this.timer = setInterval(() => this.send(), JOG_PERIOD_MS);
    },
    release(source) {
      if (!this.held.delete(source)) return;
      this.mark();
      if (this.held.size === 0 && this.timer) { clearInterval(this.timer); this.timer = null; }   // release = stop sending
      else if (this.held.size) this.send();
    },
    releaseAll() { for (const k of Array.from(this.held.keys())) this.release(k); },
    mark() {
      const active = new Set(Array.from(this.held.values()).map(({ dof, sign }) => `${dof}:${sign}`));
      for (const b of $$("button.jog")) b.classList.toggle("held", active.has(`${b.dataset.dof}:${b.dataset.sign}`));
    },
  };
  for (const b of $$("button.jog")) {
    const source = `btn:${b.dataset.dof}:${b.dataset.sign}`;
    b.addEventListener("pointerdown", (ev) => {
      ev.preventDefault();
      try { b.setPointerCapture(ev.pointerId); } catch (e) { /* synthetic events have no capture */ }
      jog.press(source, b.dataset.dof, Number(b.dataset.sign));
    });
    for (const t of ["pointerup", "pointercancel", "lostpointercapture"]) b.addEventListener(t, () => jog.release(source));
    b.addEventListener("contextmenu", (ev) => ev.preventDefault());
  }
  $("#jog-speed").addEventListener("input", () => { $("#jog-speed-out").textContent = `${$("#jog-speed").value} %`; });
  window.addEventListener("blur", () => jog.releaseAll());
  document.addEventListener("visibilitychange", () => {
    if (!document.hidden) return;
    jog.releaseAll();
    level.halt("the page was hidden: setpoints stopped, the service brakes", false, true);
  });

  // keys that edit a field: text boxes, the maneuver script boxes, drop-down lists (arrow keys choose there) —
  // never a jog or Space = STOP (typing "W" in a script jogged the hitch, a Space in it stopped it, ArrowUp on the
  // work mode list raised it: an operator's trial); Escape stops from anywhere
  // A focused slider (the jog speed) takes the arrow keys, Page Up/Down, Home and End itself: they change the
  // speed, never jog (holding ↑ on the jog speed slider raised the hitch 25 mm and left the speed at 40 %: a
  // trial); Space on it still stops
  const SLIDER_KEYS = /^(Arrow(Up|Down|Left|Right)|Page(Up|Down)|Home|End)$/;
  const typing = (ev) => {
    const t = ev.target;
    if (t instanceof HTMLInputElement && t.type === "range") return SLIDER_KEYS.test(ev.code || ev.key);
    if (t instanceof HTMLInputElement) return !["button", "submit", "reset"].includes(t.type);
    return t instanceof HTMLTextAreaElement || t instanceof HTMLSelectElement || (t instanceof HTMLElement && t.isContentEditable);
  };
  document.addEventListener("keydown", (ev) => {
    if (ev.code === "Escape" || (ev.code === "Space" && !typing(ev))) {
      ev.preventDefault();
      if (!$("#confirm").classList.contains("hidden")) $("#confirm-cancel").click();
      stop();
      return;
    }
    if (typing(ev) || ev.repeat || !KEYS[ev.code]) return;
    ev.preventDefault();
    jog.press(`key:${ev.code}`, ...KEYS[ev.code]);
  });
  document.addEventListener("keyup", (ev) => jog.release(`key:${ev.code}`));

  // ------------------------------------------------------------------ levelling (track mode, frame level)
  // On: track/start {frame: "level", dof: ["roll"], ttl_ms: 500}, then track/setpoint {roll: 0} every
  // 100 ms while the toggle is on, the page visible and the WebSocket open. Hiding the page or losing the
  // connection only stops sending: the service brakes 500 ms after the last setpoint (the dead-man).
  // Off: track/stop. What is shown comes from the state's `track` entry and the service's events.
  function limitWords(key, name) {
    const n = String(name);
    let m = /^workspace:(x|z|roll|pitch):(min|max)$/.exec(n);
    if (m) {
      const w = ui.config && ui.config.limits && ui.config.limits.workspace && ui.config.limits.workspace[m[1]];
      const v = w ? w[m[2] === "max" ? 1 : 0] : null;
      return `${m[1]} at its ${m[2] === "max" ? "upper" : "lower"} workspace limit` + (v === null ? "" : ` (${showDof(m[1], v)})`);
    }
    m = /^velocity:(x|z|roll|pitch)$/.exec(n);
    if (m) return `${m[1]} at its speed limit`;
    m = /^acceleration:(x|z|roll|pitch)$/.exec(n);
    if (m) return `${m[1]} at its acceleration limit`;
    m = /^(x|z|roll|pitch)$/.exec(key);
    if (m && /workspace/.test(n)) return `${m[1]} braking before the workspace face (${displayUnits(n)})`;
    // anything else (a stroke end, the guard's "caution: front_axle_load would be 1.212e+04 N …"): the words of
    // the main "Control limited" box (the raw guard sentence was shown here: an operator's trial)
    const [words, code] = limitedEntryWords(key, n);
    return code ? `${words} [${code}]` : words;
  }

  const level = {
    on: false, busy: false, session: null, motionId: null, seq: 0, timer: null, note: "", noteErr: false, busySession: null, motionGoneMs: null,
    async start(replace = false) {
      if (this.on || this.busy || document.body.classList.contains("viewer")) return;
      this.busy = true; this.note = "starting…"; this.noteErr = false; this.busySession = null; this.render();
      const body = { frame: "level", dof: ["roll"], ttl_ms: LEVEL_TTL_MS };
      // the session the operator agreed to take over, by its number: never another that started meanwhile
      // (work control's, say: the service refuses it then, busy)
      if (replace) body.replace = replace;
      const r = await call("track/start", body, true);
      this.busy = false;
      if (!r.ok) {
        const live = r.data.error === "busy" && /track session (\d+) \(frame (\S+), dof ([^)]*)\) is live(?: \(work control's)?/.exec(r.data.message || "");
        if (live && !replace && !/work control's/.test(r.data.message)) {
          // another client streams setpoints (hitch track, another terminal): STOP ends it; take-over = replace
          this.note = `another client is streaming setpoints (track session ${live[1]}): take over?`;
          this.render();
          const ok = await confirmDialog("Take over levelling?",
            `Another client is streaming setpoints (track session ${live[1]}, frame ${live[2]}, ${live[3]}). ` +
            "Take over ends its stream and levels the roll from this terminal; Cancel leaves it running (STOP ends it).",
            "Take over");
          if (ok) { this.start(Number(live[1])); return; }
          this.busySession = Number(live[1]);
          this.note = `not started: another client is streaming setpoints (track session ${live[1]}) — STOP ends it, or press Levelling again to take over`;
        } else if (live) {
          this.busySession = Number(live[1]);
          this.note = `not started: work control streams setpoints (track session ${live[1]}) — stop it on the Work tab, or STOP`;
        } else this.note = r.data.message || `track/start: ${r.data.error}`;
        this.noteErr = true; log(this.note, true); this.render(); return;
      }
      if (document.hidden || !ui.connected) {   // hidden while starting: never stream from a hidden page
        this.session = r.data.session; this.halt("the page was hidden: setpoints stopped, the service brakes"); return;
      }
      this.on = true; this.session = r.data.session; this.motionId = r.data.motion_id; this.seq = 0;
      this.note = ""; this.noteErr = false;
      log(`levelling on: track session ${this.session} (frame level, roll 0 mrad)`);
      this.send();
      this.timer = setInterval(() => this.send(), LEVEL_PERIOD_MS);
      this.render();
    },
    send() {
      if (!this.on || this.session === null) return;
      if (document.hidden || !ui.connected) { this.halt("the page was hidden: setpoints stopped, the service brakes", false, ui.connected); return; }
      const session = this.session;
      link.request("track/setpoint", { session, seq: this.seq++, pose: { roll: 0 } }).then((r) => {
        if (r.ok || r.data.error === "disconnected" || session !== this.session) return;
        if (r.data.error === "not_found") { this.halt(`levelling ended: ${r.data.message}`, true); return; }
        this.note = r.data.message || `setpoint refused: ${r.data.error}`; this.noteErr = true; this.render();
      });
    },
    async stop() {
      const session = this.session, motionId = this.motionId;
      this.halt("", false, true);   // the motion kept for its outcome (motion_finished: track/stop)
      if (session === null) return;
      const r = await call("track/stop", this.seq > 0 ? { session, last_seq: this.seq - 1 } : { session }, true);
      if (r.ok) {   // the motion's outcome may have come first (the same socket, other threads): it stays shown
        if (this.motionId !== null && this.motionId === motionId) { this.note = "off: braking to rest"; this.noteErr = false; }
        log(`levelling off: track/stop (session ${session})`);
      }
      else if (r.data.error !== "not_found") { this.note = r.data.message || "track/stop refused"; this.noteErr = true; log(this.note, true); }
      this.render();
    },
    // stop streaming (no request): the service brakes at the TTL
    // and forget the motion unless `keep` (its outcome is awaited: STOP, track/stop, a hidden page's TTL brake —
    // for a short while only, see draw): after a service restart an unrelated motion with the same number ending
    // said "off: replaced by preset" (an operator's trial)
    halt(why, isError = false, keep = false) {
      if (this.timer) { clearInterval(this.timer); this.timer = null; }
      const was = this.on;
      this.on = false; this.session = null;
      if (!keep) this.motionId = null;
      this.motionGoneMs = null;
      if (was && why) { this.note = why; this.noteErr = isError; }
      this.render();
    },
    // a new connection or a restarted service (its state's seq went back): motion numbers and sessions are
    // that run's own, and a refusal of before ("not connected", "busy") is no longer news
    forget(why) {
      this.motionId = null; this.busySession = null;
      if (!this.on && this.noteErr) { this.note = why; this.noteErr = false; }
      this.render();
    },
    onEvent(e) {
      if (this.motionId === null || e.motion_id !== this.motionId) return;
      if (e.event === "motion_finished" || e.event === "motion_aborted") {
        const why = e.reason || e.event.replace("motion_", "");
        this.halt("");
        this.note = `off: ${why}`; this.noteErr = why !== "track/stop";
        this.motionId = null;
        this.render();
      }
    },
    render() {
      const b = $("#level-toggle");
      b.setAttribute("aria-pressed", this.on ? "true" : "false");
      b.textContent = this.busy ? "Levelling: …" : `Levelling: ${this.on ? "on" : "off"}`;
      const st = $("#level-status");
      const zero = show_angle(0);   // in the unit the operator chose (it said mrad in degrees too)
      st.textContent = this.on ? `on · session ${this.session} · roll ${zero} to gravity`
        : (this.note ? displayUnits(this.note) : `off · roll ${zero} to gravity when on`);
      st.className = this.noteErr && !this.on ? "err" : "";
    },
    draw(s) {
      const t = s.track, counts = $("#level-counts"), box = $("#level-limited");
      if (!this.on && this.motionId !== null) {
        // the awaited outcome: the state shows the motion over for 2 s and no event came (lost over a
        // reconnect): forget it
        if (s.moving && s.motion_id === this.motionId) this.motionGoneMs = null;
        else if (this.motionGoneMs === null) this.motionGoneMs = performance.now();
        else if (performance.now() - this.motionGoneMs > 2000) { this.motionId = null; this.motionGoneMs = null; }
      }
      if (this.busySession !== null && this.busySession !== undefined && (!t || t.session !== this.busySession)) {
        this.busySession = null;   // the other client's stream ended: the refusal is no longer news
        if (!this.on && this.noteErr) { this.note = ""; this.noteErr = false; this.render(); }
      }
      if (!t) { counts.textContent = ""; box.classList.add("hidden"); return; }
      const mine = this.session !== null && t.session === this.session;
      const target = t.target && Number.isFinite(t.target.roll) ? ` · target ${show_angle(t.target.roll)}` : "";
      counts.textContent = `${mine ? "" : `track session ${t.session} (${t.frame}, ${(t.dof || []).join(", ")}) · `}` +
        `setpoints ${t.setpoints} · rejected ${t.rejected} · ignored ${t.ignored_seq}` + target +
        (t.stale ? " · stale: braking" : t.ending ? " · ending" : "");
      counts.title = "setpoints taken, rejected and ignored (old sequence numbers) by the service; target: the roll it " +
        `aims at in the tractor frame (${show_angle(0)} to gravity + the slope sensor's roll)` +
        (t.last_rejection ? `; last rejection: ${displayUnits(t.last_rejection)}` : "");
      const lim = Object.entries(t.control_limited || {});
      box.classList.toggle("hidden", lim.length === 0);
      if (lim.length) box.textContent = "Control limited: " + lim.map(([k, v]) => limitWords(k, v)).join("; ");
    },
  };
  level.render();   // the line in the unit this browser chose (the page's static text says mrad)
  $("#level-toggle").addEventListener("click", () => { if (level.on) level.stop(); else level.start(); });
  window.hitchTerminal.limitWords = limitWords;   // for the browser test

  // ------------------------------------------------------------------ tabs, goto
  for (const t of $$(".tabs button")) {
    t.addEventListener("click", () => {
      for (const o of $$(".tabs button")) o.classList.toggle("active", o === t);
      for (const p of $$(".tab")) p.classList.toggle("hidden", p.id !== `tab-${t.dataset.tab}`);
      if (t.dataset.tab === "presets") refreshPresets();
      if (t.dataset.tab === "maneuvers") refreshManeuvers();
    });
  }

  // What an operator types into a number field. The fields are text inputs (inputmode="decimal"): a browser's
  // number input drops what it cannot read ("12,5" became 125, "1e" became empty) and the page never saw it.
  // A decimal comma is a decimal point ("12,5" = 12.5); anything else that is not one plain number is refused
  // with a message in the field's unit, and nothing is sent. Returns {empty}, {value} or {error}.
  const NUMBER_RE = /^[-+−]?(?:\d+(?:[.,]\d*)?|[.,]\d+)(?:[eE][-+]?\d+)?$/;
  function readNumber(raw, label, unit) {
    const t = String(raw).trim().replace(/\s+/g, "");
    if (t === "") return { empty: true };
    const u = unit ? ` ${unit}` : "";
    if ((t.match(/[.,]/g) || []).length > 1) {
      return { error: `${label}: “${raw.trim()}” is not one number — use one decimal comma or point (e.g. 12,5${u})` };
    }
    if (!NUMBER_RE.test(t)) return { error: `${label}: “${raw.trim()}” is not a number — type a number${unit ? " in " + unit : ""} (e.g. 12,5${u})` };
    const v = Number(t.replace(",", ".").replace("−", "-"));
    if (!Number.isFinite(v)) return { error: `${label}: “${raw.trim()}” is not a finite number${unit ? " in " + unit : ""}` };
    return { value: v };
  }
  window.hitchTerminal.readNumber = readNumber;   // for the browser test

  const SPEED_MIN = 5, SPEED_MAX = 100;   // % (speed_scale 0.05–1: the service refuses less than 0.05)
  // The goto form's request, or {error}: Go and Check read the form through this one function, so Check
  // refuses exactly what Go refuses, with the same words.
  function gotoRequest() {
    const f = $("#goto-form"), goal = {};
    for (const k of DOFS) {
      const n = readNumber(f.elements[k].value, k, dofUnit(k));
      if (n.error) return { error: n.error };
      if (n.empty) continue;
      goal[k] = n.value / dofK(k);   // the form takes mm and the page's angle unit: x_mm → m, roll_mrad (or deg) → rad
    }
    if (!Object.keys(goal).length) return { error: "enter at least one of x, z, roll, pitch (empty = keep)" };
    const sp = readNumber(f.elements.speed.value, "speed", "%");
    if (sp.error) return { error: sp.error };
    const speed = sp.empty ? SPEED_MAX : sp.value;   // empty: full speed, as the field's default says
    if (!(speed >= SPEED_MIN && speed <= SPEED_MAX)) {
      return { error: `speed: ${fmt(speed, Number.isInteger(speed) ? 0 : 1)} % is outside ${SPEED_MIN}–${SPEED_MAX} % — nothing sent` };
    }
    return { goal, speed_scale: speed / 100, metres: metresInMm(goal) };
  }

  // Lengths that look typed in metres into a mm field: under 1 mm, not whole, and inside the workspace read as
  // metres (a field operator typed z = 0.25 and the hitch went to 0.25 mm). Asked about before the goto goes.
  function metresInMm(goal) {
    const w = ui.config && ui.config.limits && ui.config.limits.workspace;
    return ["x", "z"].filter((k) => k in goal && goal[k] !== 0 && Math.abs(goal[k]) < 1e-3 &&
      !Number.isInteger(goal[k] * 1000) && (!w || (goal[k] * 1000 >= w[k][0] && goal[k] * 1000 <= w[k][1])));
  }
  // the answer under a form, scrolled into its tab's view (a long refusal ran under the quick row at 1024×600)
  function result(sel, text, ok, si = false) {
    const r = $(sel), shown = si ? siUnits(text) : displayUnits(text);
    r.textContent = ok ? shown : inWords(shown);
    r.className = `result ${ok ? "ok" : "err"}`;
    if (text && r.offsetParent !== null) r.scrollIntoView({ block: "nearest" });
  }

  $("#goto-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const req = gotoRequest();
    if (req.error) { result("#goto-result", req.error, false); return; }
    if (req.metres.length) {
      // the values as typed and as meant, to 6 significant digits: "z = 0.000 mm (did you mean 0 mm?)" for 0.0001
      // typed (0.1 mm meant) had both rounded away (an operator's trial)
      const num = (v) => String(Number(v.toPrecision(6)));
      const what = req.metres.map((k) => `${k} = ${num(req.goal[k] * 1000)} mm (did you mean ${num(req.goal[k] * 1e6)} mm?)`).join(", ");
      result("#goto-result", "", true);       // the last answer is not this one's while the dialog asks
      if (!(await confirmDialog("Millimetres?", `The fields take mm: ${what}.`, "Go as typed"))) {
        result("#goto-result", `not sent: ${what}; the fields take mm`, false);
        return;
      }
    }
    delete req.metres;
    result("#goto-result", "", true);         // the last motion's outcome is no longer news
    const r = await call("goto", req);
    const ended = r.ok ? ui.outcomes.get(r.data.motion_id) : undefined;
    if (ended) { ui.gotoId = null; result("#goto-result", ...ended); return; }   // over before its reply came
    ui.gotoId = r.ok ? r.data.motion_id : null;
    result("#goto-result", r.ok ? `moving: motion #${r.data.motion_id}, ${fmt(r.data.duration, 2)} s${planGuardWords(r.data)}` : r.data.message, r.ok);
  });
  $("#goto-plan").addEventListener("click", async () => {
    const req = gotoRequest();
    if (req.error) { result("#goto-result", req.error, false); return; }
    delete req.metres;   // a check moves nothing: no question
    const r = await call("plan", req);
    if (!r.ok) result("#goto-result", r.data.message, false);
    else result("#goto-result", r.data.ok ? `reachable: ${fmt(r.data.duration, 2)} s${planGuardWords(r.data)}` : `refused: ${r.data.refused}`, r.data.ok);
  });
  // the guard's verdict on a plan in words: "(scaled)" alone did not say by how much or why (an operator's trial)
  function planGuardWords(d) {
    const f = d.speed_factor;
    if (!(Number.isFinite(f) && f < 1)) return "";
    const why = (d.reasons || []).filter((r) => r.level !== "hard").map((r) => guardReasonWords(r)).filter(Boolean);
    return ` — slowed to ${fmt(100 * f, 0)} %${why.length ? `: ${why.join("; ")}` : ""}`;
  }
  // one guard reason {measure, value, threshold, t, level, unit} in the operator's words and units (as the
  // server words the guard's sentences in the "Control limited" box: bridge/web/wording.py limited_words)
  const MEASURE_UNITS = { ssm: [1, "m", 2], lsm: [1, "m", 2], esm: [0.001, "kJ", 1] };
  function guardReasonWords(r) {
    const table = (hv.info && hv.info.words) || {}, base = table[r.measure] || r.measure.replace(/_/g, " ");
    const tractorN = hv.info && hv.info.tractor_weight_n, ok = Number.isFinite(r.value) && Number.isFinite(r.threshold);
    const bound = r.level === "hard" ? "minimum" : "slows below", when = Number.isFinite(r.t) ? ` in ${fmt(r.t, 1)} s` : "";
    if (r.measure === "front_axle_load" && ok && Number.isFinite(tractorN) && tractorN > 0) {
      return `front axle load ${fmt(100 * r.value / tractorN, 0)} % of the tractor's weight (${bound} ${fmt(100 * r.threshold / tractorN, 0)} %)${when}`;
    }
    const u = MEASURE_UNITS[r.measure];
    if (u && ok) return `${base}: ${fmt(r.value * u[0], u[2])} ${u[1]} (${bound} ${fmt(r.threshold * u[0], u[2])} ${u[1]})${when}`;
    return `${base}${when}`;
  }
  window.hitchTerminal.planGuardWords = planGuardWords;   // for the browser test
  $("#goto-current").addEventListener("click", () => {
    const p = (ui.state && ui.state.pose) || {}, f = $("#goto-form");
    for (const k of DOFS) f.elements[k].value = Number.isFinite(p[k]) ? (p[k] * dofK(k)).toFixed(dofDigits(k)) : "";
  });

  // ------------------------------------------------------------------ presets
  function item(list, name, sub, buttons) {
    const li = document.createElement("li");
    li.dataset.name = name;
    const n = document.createElement("span");
    n.className = "name"; n.textContent = name;
    const s = document.createElement("span"); s.className = "sub"; s.textContent = sub; n.appendChild(s);
    li.appendChild(n);
    for (const [label, cls, fn] of buttons) {
      const b = document.createElement("button");
      b.type = "button"; b.textContent = label; b.className = cls; b.addEventListener("click", fn);
      li.appendChild(b);
    }
    list.appendChild(li);
    return li;
  }

  async function refreshPresets() {
    const newest = asking("presets/list");
    const r = await call("presets/list", {}, true);
    if (!newest()) return;   // a later list's answer is shown already
    if (!r.ok) { ui.presetNames = null; actions.drawLock(); actions.drawRecord(); return; }   // not known: not said
    const list = $("#preset-list");
    list.textContent = "";
    // the selected implement's presets: a raise without a headland pose of its own goes to the one named "headland"
    ui.presetNames = new Set(r.data.presets.map((p) => p.name));
    actions.drawLock();
    actions.drawRecord();
    for (const p of r.data.presets) {
      // x as everywhere else, left/right of centre (+x is the driver's left); angles with the gauges' digits
      // (a signed "x 20" and pitch 0.8 mrad shown as "1": a terminal trial)
      const shown = (k) => {
        const v = p.pose[k] * dofK(k);
        if (k !== "x") return `${k} ${fmtNoNegZero(v, isLength(k) ? 0 : dofDigits(k))}`;
        return Math.abs(v) < 0.5 ? "x centre" : `x ${v > 0 ? "left" : "right"} ${fmtNoNegZero(Math.abs(v), 0)}`;
      };
      const sub = DOFS.map(shown).join(" · ") + ` (mm, ${angleUnit().unit})`;
      item(list, p.name, sub, [
        ["Go", "primary motion-only", async () => {
          const q = await call("presets/go", { name: p.name });
          if (!q.ok) return;
          // over before its reply came (a preset at the pose the hitch is at): its end, not "moving", is said last
          const ended = ui.outcomes.get(q.data.motion_id);
          if (ended) log(`preset ${p.name}: ${ended[0]}`, !ended[1]);
          else log(`preset ${p.name}: moving, ${fmt(q.data.duration, 2)} s`);
        }],
        ["Delete", "danger motion-only", async () => {
          if (!(await confirmDialog(`Delete preset ${p.name}?`, "The stored pose is removed for this implement.", "Delete"))) return;
          const q = await call("presets/delete", { name: p.name }); if (q.ok) { log(`preset ${p.name} deleted`); refreshPresets(); }
        }],
      ]);
    }
    renderUser();
  }
  $("#preset-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const name = ev.target.elements.name.value.trim();
    // a preset of this name exists (the service's list now, not what the page drew): ask before overwriting it
    const listed = await call("presets/list", {}, true);
    const old = listed.ok ? (listed.data.presets || []).find((p) => p.name === name) : null;
    if (old) {
      const was = DOFS.map((k) => `${k} ${fmt(old.pose[k] * dofK(k), dofDigits(k))} ${dofUnit(k)}`).join(" · ");
      if (!(await confirmDialog(`Overwrite preset ${name}?`, `${name} is stored at ${was}; Overwrite replaces it with the current pose.`, "Overwrite"))) {
        log(`preset ${name} not saved: it exists (kept as it was)`);
        return;
      }
    }
    const r = await call("presets/save", old ? { name, replace: true } : { name });
    if (r.ok) { log(`preset ${r.data.saved} saved at the current pose`); ev.target.reset(); refreshPresets(); }
  });

  // ------------------------------------------------------------------ maneuvers
  // the API's step index is 0-based; the operator reads step 1 … n
  // the service's own message names the step by its 0-based YAML index ("steps[1].goto.z = 250 …"): dropped after
  // the 1-based "step 2: " (the operator read "step 2: steps[1]…", two numbers for one step: a trial)
  const stepErrors = (errors) => errors.map((e) => Number.isInteger(e.step)
    ? `step ${e.step + 1}: ${String(e.message).replace(new RegExp(String.raw`^steps\[${e.step}\](?:\.|:\s*)`), "")}`
    : `script: ${e.message}`).join("; ");
  async function refreshManeuvers() {
    const newest = asking("maneuvers/list");   // the connect-time list, answered last, hid a maneuver saved since
    const r = await call("maneuvers/list", {}, true);
    if (!r.ok || !newest()) return;
    const list = $("#maneuver-list");
    list.textContent = "";
    for (const m of r.data.maneuvers) {
      ui.maneuverSteps[m.name] = m.steps;
      const buttons = [
        ["Validate", m.script === undefined ? "no-script" : "", async () => {
          if (m.script === undefined) {   // maneuvers/list gives no script: validate it from the editor
            result("#maneuver-result", `${m.name}: this service does not return stored scripts; paste the script under “New maneuver script” and press Validate (Run validates it again before moving)`, false);
            return;
          }
          const q = await call("maneuvers/validate", { script: m.script });
          if (q.ok) result("#maneuver-result", q.data.ok ? `${m.name}: valid, ${fmt(q.data.duration, 1)} s`
            : `${m.name}: ` + stepErrors(q.data.errors), q.data.ok, true);   // in the script's units (m, rad)
          else result("#maneuver-result", q.data.message, false, true);
        }],
        ["Run", "primary motion-only", async () => {
          const q = await call("maneuvers/run", { name: m.name });
          if (!q.ok) return;
          // its own end, come before this reply, stays shown; the end of the maneuver it replaced (posted before
          // the reply) is another's: it counted as this run's and "running" was never said (a review)
          // a newer run's reply came first (replies can come back out of order): this one was replaced, and
          // neither its "running" nor its end covers the newer one's
          const id = q.data.maneuver_id;
          if (Number.isInteger(id) && Number.isInteger(ui.maneuverShown) && id < ui.maneuverShown) return;
          ui.maneuverShown = id;
          if (ui.maneuverEnds.has(id)) return;
          result("#maneuver-result", `${m.name}: running, ${fmt(q.data.duration, 1)} s planned`, true);
        }],
        ["Abort", "danger", async () => { await stop(); }],
      ];
      item(list, m.name, `${m.steps} steps${m.description ? " · " + m.description : ""}`, buttons);
    }
    renderUser();
  }

  function scriptRequest() {
    const f = $("#maneuver-form");
    return { name: f.elements.name.value.trim(), script: f.elements.script.value };
  }
  $("#maneuver-validate").addEventListener("click", async () => {
    const q = await call("maneuvers/validate", { script: scriptRequest().script });
    if (!q.ok) { result("#maneuver-result", q.data.message, false, true); return; }
    result("#maneuver-result", q.data.ok ? `valid: ${fmt(q.data.duration, 1)} s from the current pose`
      : stepErrors(q.data.errors), q.data.ok, true);   // in the script's units (m, rad)
  });
  // maneuvers/save: a name saved already is refused (in_use) unless sent with replace — the operator is asked first
  async function saveManeuver(body, quiet) {
    const q = await call("maneuvers/save", body, quiet);
    if (q.ok || q.data.error !== "in_use" || !/is saved already/.test(q.data.message || "")) return q;
    const ok = await confirmDialog(`Replace maneuver ${body.name}?`,
      `A maneuver ${body.name} is saved already. Replace replaces it with this script; Cancel keeps it.`, "Replace");
    if (!ok) return { ok: false, data: { error: "in_use", message: `maneuver ${body.name} not saved: it exists (kept as it was)` } };
    return call("maneuvers/save", { ...body, replace: true }, quiet);
  }
  $("#maneuver-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const q = await saveManeuver(scriptRequest());
    if (q.ok) { result("#maneuver-result", `${q.data.saved} saved (${q.data.steps} steps)`, true); refreshManeuvers(); }
    else result("#maneuver-result", q.data.message, false, true);
  });

  function drawManeuver(man) {
    const bar = $("#maneuver-progress");
    for (const li of $$("#maneuver-list li")) li.classList.toggle("running", Boolean(man) && li.dataset.name === man.name);
    bar.classList.toggle("hidden", !man);
    if (!man) return;
    const steps = ui.maneuverSteps[man.name] || 0, step = Number.isInteger(man.step) ? man.step : 0;
    bar.querySelector(".fill").style.width = steps ? `${(100 * step / steps).toFixed(0)}%` : "0%";
    bar.querySelector(".text").textContent = `${man.name}: step ${step + 1}${steps ? " of " + steps : ""}`;
  }


  // ------------------------------------------------------------------ quick row, Implement tab, teach-in
  // The quick row (#actions, whatever tab is open): Raise / Return and pause / resume / skip of the
  // running maneuver with its progress from the state's `maneuver`, one line under it for the answers.
  // The Implement tab: the chooser, the transport lock and the implement's record and limits; the
  // Maneuvers tab: teach-in (record → review → save).
  const actions = {
    implements: [], selected: null, recording: false, busy: false,
    isViewer: () => document.body.classList.contains("viewer"),
    say(text, ok) { const r = $("#act-result"); r.textContent = ok ? displayUnits(text) : inWords(displayUnits(text)); r.title = r.textContent; r.className = `act-line result ${ok ? "ok" : "err"}`; },
    current() { return this.implements.find((i) => i.name === this.selected) || null; },
    drawLock() {
      const b = $("#act-lock"), imp = this.current(), locked = Boolean(imp && imp.transport_locked);
      b.textContent = imp ? `Lock: ${locked ? "on" : "off"}` : "Lock: —";
      b.setAttribute("aria-pressed", String(locked));
      b.disabled = this.isViewer() || !imp;
      const t = $("#imp-lock-text");
      t.textContent = !imp ? "no implement selected: raise, return and the lock need one"
        : locked ? "transport lock on: every motion but STOP is refused" : "transport lock off: the hitch may move";
      for (const id of ["#act-raise", "#act-return"]) $(id).disabled = this.isViewer() || !imp;
      if (imp && !imp.headland && this.headlandPreset() === false) $("#act-raise").disabled = true;   // nowhere to go
    },
    // whether the selected implement has a preset named "headland": true, false, or null while not known (the
    // presets not listed: Raise stays enabled, the service says if there is nowhere to go)
    headlandPreset: () => (ui.presetNames ? ui.presetNames.has("headland") : null),
    drawImplements() {
      const sel = $("#act-implement");
      sel.textContent = "";
      const names = this.implements.map((i) => i.name);
      if (!names.includes("default")) names.unshift("default");   // "no implement": the hitch alone
      for (const n of names) {
        const o = document.createElement("option");
        o.value = n; o.textContent = n === "default" ? "no implement" : n;
        sel.appendChild(o);
      }
      sel.value = this.selected || "";
      sel.disabled = this.isViewer();
      this.drawLock();
      this.drawRecord();
    },
    // the selected implement's record and limits in operator units (what implements/list says)
    drawRecord() {
      const dl = $("#imp-limits"), imp = this.current(), rows = [];
      dl.textContent = "";
      const zero = (k, v) => (Math.abs(v * dofK(k)) < 0.05 ? 0 : v);   // no "-0.0"
      const pose = (p) => p ? DOFS.filter((k) => Number.isFinite(p[k])).map((k) => k === "x" ? show_x(p.x) : `${k} ${showDof(k, zero(k, p[k]))}`).join(" · ") : null;
      if (!imp) rows.push(["implement", this.selected === "default" || !this.selected ? "none (the hitch alone)" : this.selected]);
      else {
        rows.push(["category, mass", `ISO 730 cat. ${imp.category} · ${fmt(imp.mass_kg, 0)} kg`]);
        if (Array.isArray(imp.com_m)) rows.push(["centre of mass", `${imp.com_m.map((v) => fmt(v * 1000, 0)).join(" · ")} mm (x · y · z)`]);
        rows.push(["upper height", Number.isFinite(imp.upper_height_m) ? `${show_mm(imp.upper_height_m)} (tool point z)` : "no limit"]);
        rows.push(["lowering speed", Number.isFinite(imp.lowering_speed_m_s) ? `${fmt(imp.lowering_speed_m_s * 1000, 0)} mm/s` : "no limit"]);
        const preset = this.headlandPreset();
        rows.push(["headland pose", pose(imp.headland) || (preset ? "the preset “headland”" : preset === false
          ? "none: define one, or save a preset named “headland” (Raise needs it)" : "the preset “headland”, if saved")]);
        rows.push(["last work pose", pose(imp.last_work) || "none yet (set by a raise)"]);
        rows.push(["source", imp.source === "profile" ? "tractor profile (stored when selected)" : "stored"]);
        if (imp.description) rows.push(["description", imp.description]);
      }
      for (const [k, v] of rows) {
        const dt = document.createElement("dt"), dd = document.createElement("dd");
        dt.textContent = k; dd.textContent = v; dd.title = v; dl.append(dt, dd);
      }
    },
    // the running maneuver's step, kind and what is left, from the state
    draw(s) {
      const man = s.maneuver, viewer = this.isViewer(), p = $("#act-progress");
      this.followMotion(s);
      $("#act-pause").disabled = viewer || !man || Boolean(man.paused);
      $("#act-resume").disabled = viewer || !man || !man.paused;
      $("#act-skip").disabled = viewer || !man;
      this.drawLock();
      const rec = $("#act-record");
      rec.setAttribute("aria-pressed", String(this.recording));
      rec.textContent = this.recording ? "■ Stop rec." : "● Record";
      if (!man) { p.textContent = "no maneuver running"; p.className = "act-line idle"; return; }
      const steps = ui.maneuverSteps[man.name] || 0, step = Number.isInteger(man.step) ? man.step + 1 : "—";
      let text = `${man.name || "maneuver"}: step ${step}${steps ? " of " + steps : ""}`;
      if (man.kind) text += ` · ${man.kind.replace("_", " ")}`;
      if (Number.isFinite(man.time_left)) text += ` · ${fmt(man.time_left, 1)} s left`;
      if (Number.isFinite(man.distance_left)) text += ` · ${fmt(man.distance_left, 1)} m left`;
      if (man.paused) text += " · paused";
      p.textContent = text; p.title = text;
      p.className = `act-line ${man.paused ? "paused" : "running"}`;
    },
  };
  window.hitchTerminal.actions = actions;   // for the browser test

  async function refreshImplements() {
    const newest = asking("implements/list");
    const r = await call("implements/list", {}, true);
    if (!r.ok || !newest()) return;
    actions.implements = r.data.implements || [];
    actions.selected = r.data.selected;
    actions.drawImplements();
  }

  async function actionCall(key, payload, okText) {
    const r = await call(key, payload);
    if (r.ok) actions.say(okText(r.data), true); else actions.say(r.data.message || `${key}: ${r.data.error}`, false);
    return r;
  }
  // Raise / Return: "moving" while the motion runs, then its end (the motion_finished / motion_aborted event,
  // or the outcome that came before the reply); the state's motion ending without an event says "ended".
  async function quickMotion(key, what) {
    actions.motion = null;
    const r = await actionCall(key, {}, (d) => `${what}: moving, motion #${d.motion_id}, ${fmt(d.duration, 1)} s`);
    if (!r.ok || !Number.isInteger(r.data.motion_id)) return r;
    actions.motion = { id: r.data.motion_id, what, seen: false };
    const ended = ui.outcomes.get(r.data.motion_id);
    if (ended) actions.motionEnded(r.data.motion_id, ended[0], ended[1]);
    return r;
  }
  actions.motionEnded = function motionEnded(id, text, ok) {
    const m = this.motion;
    if (!m || m.id !== id) return;
    this.motion = null;
    this.say(`${m.what}: ${ok ? `motion #${id} finished` : text}`, ok);
  };
  // from the state: the motion is no longer the one running (its end event may be lost over a reconnect)
  actions.followMotion = function followMotion(s) {
    const m = this.motion;
    if (!m) return;
    if (s.moving && s.motion_id === m.id) { m.seen = true; return; }
    if (!m.seen && !(Number.isInteger(s.motion_id) && s.motion_id > m.id)) return;   // not started in the state yet
    if (!m.endSeenMs) { m.endSeenMs = performance.now(); return; }
    if (performance.now() - m.endSeenMs > 1000) {   // no event within 1 s of the state's end: say what is known
      this.motion = null;
      this.say(`${m.what}: motion #${m.id} ended`, true);
    }
  };
  $("#act-raise").addEventListener("click", async () => {
    const r = await quickMotion("hitch/raise", "raise");
    if (r.ok) refreshImplements();   // the raise's start became the implement's last work pose
  });
  $("#act-return").addEventListener("click", () => quickMotion("hitch/return", "return"));
  $("#act-lock").addEventListener("click", async () => {
    const imp = actions.current();
    if (!imp) return;
    const key = imp.transport_locked ? "implements/unlock" : "implements/lock";
    const r = await actionCall(key, {}, (d) => `${d.implement}: transport lock ${d.transport_locked ? "on: every motion but STOP is refused" : "off"}`);
    if (r.ok) await refreshImplements();
  });
  $("#act-implement").addEventListener("change", async (ev) => {
    const name = ev.target.value;
    const r = await actionCall("implements/select", { name }, (d) => `implement: ${d.selected === "default" ? "none (the hitch alone)" : d.selected}`);
    await refreshImplements();   // refused (e.g. while moving): the chooser shows the selected one again
    if (r.ok) refreshPresets();
  });
  $("#act-record").addEventListener("click", async () => {
    if (!actions.recording) {
      const r = await actionCall("maneuvers/record/start", {}, () => "recording: your gotos, presets and jogs become steps");
      if (r.ok) actions.recording = true;
      if (ui.state) actions.draw(ui.state);
      return;
    }
    const r = await call("maneuvers/record/stop", {});
    actions.recording = false;
    if (ui.state) actions.draw(ui.state);
    if (!r.ok) { actions.say(r.data.message, false); return; }
    actions.say(`recorded ${r.data.steps} steps: review and save`, true);
    review.open(r.data.script, r.data.steps);
  });
  for (const [id, action] of [["#act-pause", "pause"], ["#act-resume", "resume"], ["#act-skip", "skip"]]) {
    $(id).addEventListener("click", () => actionCall(`maneuvers/${action}`, {}, (d) => {
      const m = d.maneuver;
      return `maneuver ${{ pause: "paused", resume: "resumed", skip: "skipped" }[action]}` + (m && Number.isInteger(m.step) ? `: step ${m.step + 1}` : "");
    }));
  }

  // the recorded script for review: edit, Save as → maneuvers/save; Cancel discards it
  const review = {
    open(script, steps) {
      $("#review-title").textContent = `Recorded maneuver: ${steps} step${steps === 1 ? "" : "s"}`;
      $("#review-script").value = script;
      const m = /^name:\s*([A-Za-z0-9][A-Za-z0-9_.\-]*)/m.exec(script);
      $("#review-name").value = m ? m[1] : "";
      $("#review-result").textContent = "";
      $("#review").classList.remove("hidden");
      $("#review-name").focus();
    },
    close() { $("#review").classList.add("hidden"); },
  };
  $("#review-cancel").addEventListener("click", () => { review.close(); actions.say("recording discarded", true); });
  $("#review-save").addEventListener("click", async () => {
    const name = $("#review-name").value.trim();
    if (!name) { result("#review-result", "enter a name: 1–64 of A–Z a–z 0–9 _ . -", false); return; }
    const q = await saveManeuver({ name, script: $("#review-script").value }, true);
    if (!q.ok) { result("#review-result", q.data.message, false); return; }
    review.close();
    actions.say(`${q.data.saved} saved (${q.data.steps} steps)`, true);
    refreshManeuvers();
  });

  // ------------------------------------------------------------------ work control (the Work tab)
  // Mode, settings (draft setpoint in kN, blend, depth limits in cm: the API's N and m), Start/Stop and
  // Resume after a fallback; the state's `work` block in words. Self-contained: it follows ui.state on
  // its own timer and reads the selected implement's settings (work/settings) on each connection.
  const work = {
    settings: null, implement: undefined, ws: null, shown: null, stopping: null,
    kn: (n) => (Number.isFinite(n) ? (n / 1000).toFixed(1) : "—"),
    cm: (m) => (Number.isFinite(m) ? String(Number((m * 100).toFixed(1))) : "—"),   // the dialog's 0.1 cm steps
    take(d) {
      this.settings = d.settings; this.implement = d.implement;
      $("#work-mode").value = d.settings.mode;
      if (ui.state) this.draw(ui.state);   // the summary says the new settings now, not at the next state message
    },
    // a read and a change answer alike (the settings then): an answer older than one shown is not drawn (the
    // connect-time read, answered after a mode chosen meanwhile, put the old mode back in the selector)
    async load() {
      const newest = asking("work/settings");
      const r = await call("work/settings", {}, true);
      if (r.ok && newest()) this.take(r.data);
      return r;
    },
    async put(payload) {
      const newest = asking("work/settings");
      const r = await call("work/settings", payload, true);
      if (r.ok && newest()) this.take(r.data); else if (this.settings) $("#work-mode").value = this.settings.mode;
      return r;
    },
    // the work block in words, e.g. "draft control · draft 21.3 kN (setpoint 20.0 kN) · depth 18 cm"
    words(w) {
      const mode = (this.settings && this.settings.mode) || (w && w.mode) || "position";
      if (!w || !w.running) {
        const sp = this.settings && mode !== "position" && mode !== "float" ? ` (setpoint ${this.kn(this.settings.draft_setpoint_n)} kN)` : "";
        return `work control: off · ${mode}${sp}`;
      }
      const parts = [];
      if (w.fallback) parts.push(`fallback: ${String(w.fallback).replace(/^(.*?): (.*)$/, "$1 ($2)")} — position control`);
      else parts.push(`${w.active || w.mode} control`);
      if (w.mode !== "position" || Number.isFinite(w.draft_n)) {
        parts.push(`draft ${Number.isFinite(w.draft_n) ? this.kn(w.draft_n) + " kN" : "—"} (setpoint ${this.kn(w.draft_setpoint_n)} kN)`);
      }
      if (Number.isFinite(w.depth_m)) parts.push(`depth ${this.cm(w.depth_m)} cm`);
      if (w.limited && w.limited.depth) parts.push(w.limited.depth === "work:depth_max" ? "at max depth" : "at min depth");
      return parts.join(" · ");
    },
    draw(s) {
      const w = s.work, viewer = document.body.classList.contains("viewer"), running = Boolean(w && w.running);
      const b = $("#work-toggle"), st = $("#work-status");
      b.setAttribute("aria-pressed", String(running));
      b.textContent = running ? "■ Stop" : "▶ Start";
      b.disabled = viewer;
      $("#work-mode").disabled = viewer;
      $("#work-settings").disabled = viewer;
      $("#work-resume").disabled = viewer || !running || !w.fallback;
      // "work session N: stopping" on the quick row's line becomes "ended" once the state says so (it stayed)
      const ending = this.stopping;
      if (ending && !running) {
        this.stopping = null;
        if ($("#act-result").textContent === ending.text) actions.say(`work session ${ending.session}: ended`, true);
      }
      const text = this.words(w);
      st.textContent = text; st.title = text;
      st.className = `work-line ${running ? (w.fallback ? "fallback" : "running") : ""}`;
      const set = this.settings, sum = $("#work-summary");
      sum.textContent = set ? `settings${this.implement ? ` of ${this.implement === "default" ? "no implement" : this.implement}` : ""}: ` +
        `${set.mode} · draft setpoint ${this.kn(set.draft_setpoint_n)} kN · blend ${set.blend} · depth ${this.cm(set.depth_min_m)}–${this.cm(set.depth_max_m)} cm`
        : "settings: —";
    },
    tick() {
      if (!ui.state) return;
      if (link.ws !== this.ws || (actions.selected && actions.selected !== this.implement)) {
        this.ws = link.ws; this.implement = actions.selected || this.implement;
        this.load();
      }
      if (ui.state !== this.shown) { this.shown = ui.state; this.draw(ui.state); }
    },
    openDialog() {
      const s = this.settings;
      if (!s) return;
      const f = $("#work-form");
      f.draft_kn.value = (s.draft_setpoint_n / 1000).toFixed(1);
      f.blend.value = String(s.blend);
      f.depth_min_cm.value = (s.depth_min_m * 100).toFixed(1);
      f.depth_max_cm.value = (s.depth_max_m * 100).toFixed(1);
      $("#work-form-result").textContent = "";
      $("#work-dialog").classList.remove("hidden");
    },
  };
  window.hitchTerminal.work = work;   // for the browser test
  setInterval(() => work.tick(), 100);
  $("#work-mode").addEventListener("change", async (ev) => {
    const r = await work.put({ mode: ev.target.value });
    actions.say(r.ok ? `work mode: ${r.data.settings.mode}` : r.data.message, r.ok);
  });
  $("#work-settings").addEventListener("click", async () => { await work.load(); work.openDialog(); });
  $("#work-cancel").addEventListener("click", () => $("#work-dialog").classList.add("hidden"));
  // The dialog's fields in their own units: [input, label, unit, the API's key, SI per field unit, lo, hi, lo open]
  const WORK_FIELDS = [
    ["draft_kn", "draft", "kN", "draft_setpoint_n", 1000, 0, 300, true],
    ["blend", "blend", "", "blend", 1, 0, 1, false],
    ["depth_min_cm", "depth min", "cm", "depth_min_m", 0.01, 0, 60, false],
    ["depth_max_cm", "depth max", "cm", "depth_max_m", 0.01, 0, 60, false],
  ];
  const workNum = (v) => String(Number(v.toPrecision(6)));
  // The service's refusal of work/settings (SI: N, m, its field names) in the dialog's units and labels:
  // "draft_setpoint_n = 20000000.0 is outside the allowed range (0, 300000] N" → "draft = 20000 kN is outside
  // the allowed range (0, 300] kN"; "depth_min_m = 0.4 must be below depth_max_m = 0.3 (both in [0, 0.6])" →
  // "depth min = 40 cm must be below depth max = 30 cm (both in [0, 60] cm)".
  function workUnits(text) {
    if (typeof text !== "string") return text;
    const N = String.raw`[-−+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?`;
    const num = (t) => Number(t.replace("−", "-"));
    let t = text.replace(/;?\s*did you mean (?:mm|degrees|mrad)\?[^;)]*/g, "");
    // ranges with a unit: (0, 300000] N → (0, 300] kN; [0, 0.6] m → [0, 60] cm
    t = t.replace(new RegExp(String.raw`([\[(])\s*(${N})\s*,\s*(${N})\s*\]\s*(N|m)\b`, "g"), (_, o, a, b, u) =>
      u === "N" ? `${o}${workNum(num(a) / 1000)}, ${workNum(num(b) / 1000)}] kN` : `${o}${workNum(num(a) * 100)}, ${workNum(num(b) * 100)}] cm`);
    // the depth pair's range without a unit: "(both in [0, 0.6])"
    t = t.replace(new RegExp(String.raw`both in \[\s*(${N})\s*,\s*(${N})\s*\](?!\s*(?:cm|kN))`, "g"),
      (_, a, b) => `both in [${workNum(num(a) * 100)}, ${workNum(num(b) * 100)}] cm`);
    // each field by its label, its value in the field's unit
    const names = { draft_setpoint_n: ["draft", "kN", 1e-3], draft_max_n: ["draft limit", "kN", 1e-3],
      depth_min_m: ["depth min", "cm", 100], depth_max_m: ["depth max", "cm", 100] };
    for (const [key, [label, unit, k]] of Object.entries(names)) {
      t = t.replace(new RegExp(String.raw`\b${key}\s*=\s*(${N})`, "g"), (_, a) => `${label} = ${workNum(num(a) * k)} ${unit}`);
      t = t.replace(new RegExp(String.raw`\b${key}\b`, "g"), label);
    }
    return t;
  }
  window.hitchTerminal.workUnits = workUnits;   // for the browser test
  // the dialog's values → the API's body in SI, or {error} in the dialog's units (nothing is sent)
  function workRequest(f) {
    const body = {}, shown = {};
    for (const [name, label, unit, key, scale, lo, hi, openLo] of WORK_FIELDS) {
      const n = readNumber(f[name].value, label, unit);
      const rng = `${openLo ? "(" : "["}${lo}, ${hi}] ${unit || ""}`.trim();
      if (n.error) return { error: n.error };
      if (n.empty) return { error: `${label}: enter a number in ${rng}` };
      const u = unit ? ` ${unit}` : "";
      if (n.value > hi || n.value < lo || (openLo && n.value <= lo)) {
        return { error: `${label} = ${workNum(n.value)}${u} is outside ${rng} [${key}] — nothing saved` };
      }
      // depths in steps of 0.1 cm, what the page shows (0.001–0.002 cm was taken and summarised as "0–0 cm")
      if (unit === "cm" && Math.abs(n.value * 10 - Math.round(n.value * 10)) > 1e-6) {
        return { error: `${label} = ${workNum(n.value)} cm: the depth is set in steps of 0.1 cm (e.g. ${fmt(n.value, 1)} cm) — nothing saved` };
      }
      body[key] = n.value * scale; shown[key] = `${workNum(n.value)}${u}`;
    }
    if (!(body.depth_min_m < body.depth_max_m)) {
      return { error: `depth min = ${shown.depth_min_m} must be below depth max = ${shown.depth_max_m} — nothing saved` };
    }
    return { body };
  }
  $("#work-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const req = workRequest(ev.target);
    if (req.error) { result("#work-form-result", req.error, false); return; }
    const r = await work.put(req.body);
    if (!r.ok) { result("#work-form-result", workUnits(r.data.message || r.data.error), false); return; }
    $("#work-dialog").classList.add("hidden");
    const s = r.data.settings;
    actions.say(`work settings saved: ${s.mode}, draft ${work.kn(s.draft_setpoint_n)} kN, blend ${s.blend}, depth ${work.cm(s.depth_min_m)}–${work.cm(s.depth_max_m)} cm`, true);
  });
  $("#work-toggle").addEventListener("click", async () => {
    const running = Boolean(ui.state && ui.state.work && ui.state.work.running);
    if (running) {
      const r = await actionCall("work/stop", {}, (d) => `work session ${d.session}: stopping`);
      if (r.ok) work.stopping = { session: r.data.session, text: $("#act-result").textContent };
    }
    else await actionCall("work/start", {}, (d) => `work session ${d.session} started: ${d.work.mode}`);
  });
  $("#work-resume").addEventListener("click", () => actionCall("work/resume", {}, (d) => `work: ${d.mode} again`));

  for (const b of $$(".motion-only")) b.dataset.title = b.title || "";
  renderHelp();
  renderConnection();
  checkSession("");
})();
