// Rita operator console: one WebSocket to `ritactl console`, plain DOM + canvas, no build step.
// Protocol: docs/operations.md, "Operator console". `window.rita` exposes counters for tests and the benchmark.
"use strict";
const $ = (id) => document.getElementById(id);
const ROLES = ["viewer", "operator", "admin"];
const S = {
  ws: null, role: "unknown", commands: {}, calls: new Map(), nextId: 1, backoff: 500,
  view: { width: 640, fps: 5, roi: null }, meta: null, pendingMeta: null,
  framesDrawn: 0, latencies: [], job: null, jobs: [], dataDir: "", connects: 0, procedures: [],
  fresh: {},   // source -> Date.now() of its last value: what markStale greys
};
window.rita = S;

// ------------------------------------------------------------------ link
function connect() {
  const ws = new WebSocket(`ws://${location.host}/ws`);
  ws.binaryType = "blob";
  S.ws = ws;
  ws.onopen = () => { S.backoff = 500; S.connects += 1; sendView(); slowPoll(); };
  ws.onclose = () => {
    setLink("page link lost: reconnecting", false);
    for (const p of S.calls.values()) p.reject({ code: "link", message: "the link to the console dropped" });
    S.calls.clear();
    setTimeout(connect, S.backoff);          // reconnect by itself, backing off to 5 s
    S.backoff = Math.min(S.backoff * 2, 5000);
  };
  ws.onmessage = (ev) => {
    if (typeof ev.data !== "string") { drawFrame(S.pendingMeta, ev.data); return; }
    const m = JSON.parse(ev.data);
    if (m.type === "hello") onHello(m);
    else if (m.type === "state") onState(m);
    else if (m.type === "frame") S.pendingMeta = m;
    else if (m.type === "reply") {
      const p = S.calls.get(m.id);
      if (p) { S.calls.delete(m.id); m.ok ? p.resolve(m.result) : p.reject(m.error); }
    } else if (m.type === "error") toast(m.message);
  };
}
function send(o) { if (S.ws && S.ws.readyState === 1) S.ws.send(JSON.stringify(o)); }
function request(msg, what, timeout = 30) {  // one message with an id; its reply resolves or rejects
  return new Promise((resolve, reject) => {
    const id = S.nextId++;
    S.calls.set(id, { resolve, reject });
    send({ ...msg, id });
    setTimeout(() => { if (S.calls.delete(id)) reject({ code: "timeout", message: `${what}: no answer in ${timeout + 5} s` }); },
               (timeout + 5) * 1000);
  });
}
function call(cmd, args = {}, timeout = 30) { return request({ op: "call", cmd, args, timeout }, cmd, timeout); }
function act(cmd, args = {}, timeout = 60) {  // a control's command: errors go to the toast, never silently
  return call(cmd, args, timeout).catch((e) => { toast(`${cmd}: ${e.message} [${e.code}]`); throw e; });
}
function toast(text) { $("toast").textContent = text; clearTimeout(S.toastTimer); S.toastTimer = setTimeout(() => { $("toast").textContent = ""; }, 8000); }
function setLink(text, ok) { $("link").textContent = text; $("link").className = "pill " + (ok ? "ok" : "bad"); }
const fmt = (v, d = 3) => (v === null || v === undefined || typeof v === "object" || !Number.isFinite(Number(v))) ? "–" : Number(v).toFixed(d);
function live(id, text) { const el = $(id); el.textContent = text; delete el.dataset.was; }  // a fresh value replaces a stale mark

// ------------------------------------------------------------------ staleness
// A panel whose source is silent (the daemon died, the link dropped) is greyed with its age, and its key values
// say they are unknown instead of repeating the last one ("locked", IDLE, "alive true").
const SOURCES = { "robot-panel": ["robot.state", 3000], "daemon-panel": ["daemon.health", 3500],
                  "tracker-panel": ["tracker.status", 4000], "camera-panel": ["camera.status", 4000] };
function markStale() {
  const now = Date.now();
  for (const [panel, [src, limit]] of Object.entries(SOURCES)) {
    const seen = S.fresh[src], age = seen ? now - seen : Infinity, stale = age > limit, p = $(panel);
    p.classList.toggle("stale", stale);
    p.querySelector(".age").textContent = stale ? (seen ? `stale: nothing from ${src} for ${fmt(age / 1000, 0)} s` : "no data yet") : "";
    if (!stale) continue;
    for (const el of p.querySelectorAll("[data-live]")) {
      if (el.dataset.was === undefined && el.textContent && el.textContent !== "?") { el.dataset.was = el.textContent; el.textContent = `unknown (was ${el.dataset.was})`; }
    }
  }
  renderRobotState();   // robot.js: says unknown by itself when its sources are silent
}

// ------------------------------------------------------------------ roles
function allowed(cmd) {
  const need = S.commands[cmd];
  return need !== undefined && ROLES.indexOf(S.role) >= ROLES.indexOf(need);
}
function applyRole() {
  $("role").textContent = S.role;
  $("viewer-note").hidden = S.role !== "viewer";
  // every control names its command in data-cmd; its inputs follow the panel's commands
  for (const el of document.querySelectorAll("[data-cmd]")) el.disabled = !allowed(el.dataset.cmd) || el.dataset.busy === "1";
  const canOperate = allowed("robot.move");
  for (const el of document.querySelectorAll("input.ctl, select.ctl, textarea.ctl")) el.disabled = !canOperate;
  $("proc-cancel").disabled = $("proc-cancel").disabled || !S.job || !["queued", "running", "waiting"].includes(S.job.state);
  const chosenRuns = (S.jobs || []).some((j) => j.procedure === $("proc").value && ["queued", "running", "waiting"].includes(j.state));
  // one job of a procedure at a time; one that drives not while the STOP is latched (ritad refuses it)
  const chosenDrives = ((S.procInfo || {})[$("proc").value] || {}).moves !== false;
  const latched = !!S.latch && S.latch.latched;
  $("proc-start").disabled = $("proc-start").disabled || chosenRuns || (chosenDrives && latched);
  $("proc-resume").disabled = $("proc-resume").disabled || !S.job || !["failed", "cancelled", "stopped"].includes(S.job.state)
    || (S.job.state === "stopped" && S.latch && S.latch.latched);
  gateMotions();   // robot.js: Move…/Turn… and the dialog's Move only when no latch and no driving job
}
function onHello(m) {
  S.seriesSpec = m.series || {};   // live.js: the plotted series' names and units
  S.role = m.role; S.commands = m.commands; S.procedures = m.procedures; S.procParams = m.procedure_params; S.procInfo = m.procedure_info || {};
  const sel = $("proc");
  if (!sel.options.length) { for (const p of m.procedures) sel.add(new Option(p, p)); renderProcForm(); }
  applyRole();
}

// ------------------------------------------------------------------ telemetry
function onState(m) {
  const up = m.link.bus === "up";
  setLink(up ? "robot link up" : `robot link ${m.link.bus}: ${m.link.error}`, up);
  const t = m.topics;
  for (const k of Object.keys(t)) S.fresh[k] = Date.now();   // topics that changed since this page's last state
  if (t["daemon.health"]) showHealth(t["daemon.health"].data);
  if (t["robot.state"]) showRobot(t["robot.state"].data);
  if (t["tracker.point"]) showPoint(t["tracker.point"].data, t["tracker.point"].t_ns);
  if (t["robot.latch"]) showLatch(t["robot.latch"].data);   // robot.js: the one latch state
  addSeries(m.series);   // live.js: the plotted points this page has not had, and the pose they end on
  for (const e of m.events) onEvent(e);
  renderRobotState();   // robot.js: the Robot and Daemon panels' one robot state
  if (m.survey) showSurvey(m.survey);   // survey.js: sent when it changed
  const c = m.console;
  $("console-stats").textContent = `console: pictures to pages ${c.frames_sent}, tabs ${c.tabs}; ` +
    `this page drew ${S.framesDrawn}${c.preview_error ? "; camera: " + c.preview_error : ""}`;
}
function showHealth(h) {   // built as elements: device names, states and reasons are text, never markup
  S.robotDevice = (h.devices || {}).robot || null;
  const rows = Object.entries(h.devices || {}).map(([k, s]) => {
    const state = el("span", { className: `st st-${s.state}`, textContent: s.state });
    if (k === "robot") state.dataset.robotState = "";   // robot.js writes the Robot panel's state here too
    return el("tr", {}, el("th", { textContent: k }), el("td", {}, state),
              el("td", { textContent: `reconnects ${s.reconnects}` }),
              el("td", { textContent: s.reason || "" }));
  });
  const drops = Object.values((h.telemetry || {}).dropped || {}).reduce((a, b) => a + b, 0);
  const frames = h.frames || {};
  const alive = el("b", { textContent: String(h.alive), dataset: { live: "" } });
  $("daemon-health").replaceChildren(
    el("div", {}, `up ${fmt(h.uptime_s, 0)} s, alive `, alive),
    el("table", {}, ...rows),
    el("div", { textContent: `telemetry dropped ${drops}; frames sent ${frames.sent}, ` +
                             `dropped ${frames.dropped}` }));
  renderRobotState();
}
function showRobot(r) {
  S.robotBase = r;   // its state: robotSummary (robot.js), with the device's and the latch's
  // its pose: live.js showPose, from the newest pose point (odometry, or this status from a base without)
  $("robot-tilt").textContent = r.roll_deg === null ? "no inclinometer" : `roll ${fmt(r.roll_deg)}°, pitch ${fmt(r.pitch_deg)}°`;
  $("robot-battery").textContent = `${fmt(r.battery_v, 1)} V`;
  stamp("robot-status-age", Date.now());   // live.js: the status as this page received it
}
function stopNow() { act("robot.stop", {}, 10).then(() => toast("robot stopped and latched")).catch(() => {}); }
function closeDialogs() {  // Esc: each open dialog's Cancel
  for (const d of document.querySelectorAll(".modal")) {
    if (!d.hidden) d.querySelector(".view, button:last-child")?.click();
  }
}
function onKey(ev) {  // capture phase: before a focused button or field sees the key
  const typing = ev.target instanceof HTMLElement && ev.target.matches("input, textarea, select");
  if (ev.code === "Space" && (ev.ctrlKey || !typing)) { ev.preventDefault(); ev.stopPropagation(); if (ev.type === "keydown" && !ev.repeat) stopNow(); }
  else if (ev.key === "Escape" && ev.type === "keydown") closeDialogs();
}
function showPoint(p, tNs) {
  const i = (p.n || 1) - 1, sampled = Array.isArray(p.t_ns) ? p.t_ns[i] : p.host_time_ns;
  if (p.x && p.x.length) {   // its age: since the page got it, plus how old it was when published
    $("tracker-point").textContent = `${fmt(p.x[i])}, ${fmt(p.y[i])}, ${fmt(p.z[i])} mm (stream)`;
    const lag = Number.isFinite(sampled) && sampled <= tNs ? (tNs - sampled) / 1e6 : 0;
    stamp("tracker-point-age", Date.now() - lag);
  }
  const now = tNs / 1e9;
  if (S.lastPointT) $("tracker-rate").textContent = `${fmt((p.n || 1) / Math.max(1e-3, now - S.lastPointT), 0)} points/s`;
  S.lastPointT = now;
}
function onEvent(e) {
  if (e.topic === "robot.event") {   // a motion's end in words, not its whole record
    const r = e.data || {};
    toast(r.event ? `robot: ${r.event}${r.result ? " " + r.result : ""}${r.reason ? " (" + r.reason + ")" : ""}` : `robot: ${JSON.stringify(r).slice(0, 120)}`);
  }
  const d = e.data || {};
  if (e.topic === "robot.latch") noteLatch(d);   // every engagement, even one released within a state period
  if (e.topic === "calib.prompt" && d.job && (!S.pinned || (S.job && S.job.job === d.job))) {
    showPrompt({ job: d.job, state: "waiting", prompt: d });   // at once, even when another client answers quickly
  }
  if (e.topic.startsWith("calib.")) refreshJobs();
  if (e.topic === "calib.result") refreshResults();   // whoever finished it: active calibration and history
}
async function slowPoll() {  // state that has no telemetry topic: polled, cheap, viewer-allowed commands
  if (!S.ws || S.ws.readyState !== 1) return;
  try {
    const t = await call("tracker.status", {}, 5);
    S.fresh["tracker.status"] = Date.now();
    const locked = t.tracker_status === "Ready";
    live("tracker-locked", locked ? "locked" : "not locked");
    $("tracker-status").textContent = `(${t.tracker_status})`;
    if (!t.streaming) $("tracker-rate").textContent = "not streaming";
    const c = await call("camera.status", {}, 5);
    S.cameraStatus = c;
    S.fresh["camera.status"] = Date.now();
    if (!S.dataDir) S.dataDir = (await call("data.dir", {}, 5)).data_dir;
    await refreshJobs();
  } catch (e) { /* the link or the daemon is down: the link pill says so */ }
  clearTimeout(S.pollTimer);
  S.pollTimer = setTimeout(slowPoll, 1000);
}

// ------------------------------------------------------------------ camera
function sendView() {
  S.view.width = Number($("view-width").value);
  S.view.fps = Number($("view-fps").value);
  send({ op: "view", ...S.view });
  send({ op: "next" });
}
async function drawFrame(meta, blob) {
  S.pendingMeta = null;
  if (!meta) return;
  try {
    const bmp = await createImageBitmap(blob);
    const cv = $("cam"), ctx = cv.getContext("2d");
    if (cv.width !== bmp.width || cv.height !== bmp.height) { cv.width = bmp.width; cv.height = bmp.height; }
    ctx.drawImage(bmp, 0, 0);
    cv.classList.remove("empty");   // a picture: the canvas takes the panel's width at the frame's aspect
    if ($("crosshair").checked) {
      ctx.strokeStyle = "#ff1744"; ctx.lineWidth = 1; ctx.beginPath();
      const cx = ((meta.full_w / 2 - meta.x) / meta.step), cy = ((meta.full_h / 2 - meta.y) / meta.step);
      ctx.moveTo(cx, 0); ctx.lineTo(cx, cv.height); ctx.moveTo(0, cy); ctx.lineTo(cv.width, cy); ctx.stroke();
    }
    if (window.drawDetection) drawDetection(ctx, meta);   // detect.js: the last detection's corners or mark
    S.meta = meta;
    S.framesDrawn += 1;
    S.latencies.push(Date.now() - meta.host_time_ns / 1e6);   // acquisition → drawn, same host clock
    if (S.latencies.length > 5000) S.latencies.shift();
    const cs = S.cameraStatus || {};
    const ap = cs.applied || {};  // the GenICam node values the camera took (SFNC names)
    const exp = meta.exposure_us ?? ap.ExposureTime ?? ap.exposure_us, gain = meta.gain_db ?? ap.Gain ?? ap.gain_db;
    $("cam-info").textContent = `frame ${meta.frame_id} (${meta.full_w}×${meta.full_h}, shown 1:${meta.step}` +
      `${meta.step === 1 && meta.w < meta.full_w ? `, region ${meta.x},${meta.y}` : ""}); exposure ${fmt(exp, 0)} µs; gain ${fmt(gain, 1)} dB`;
  } finally {
    send({ op: "next" });  // pull: the console sends the next picture only now, so a slow page just gets fewer
  }
}
function zoomAt(ev) {
  const m = S.meta;
  if (!m) return;
  const cv = $("cam"), r = cv.getBoundingClientRect();
  const fx = m.x + ((ev.clientX - r.left) * cv.width / r.width) * m.step;
  const fy = m.y + ((ev.clientY - r.top) * cv.height / r.height) * m.step;
  const w = S.view.width, h = Math.round(w * 3 / 4);   // one screen pixel per sensor pixel
  S.view.roi = [Math.max(0, Math.round(fx - w / 2)), Math.max(0, Math.round(fy - h / 2)), w, h];
  $("zoom-reset").disabled = false;
  sendView();
}

// ------------------------------------------------------------------ controls
function bind() {
  $("stop").onclick = stopNow;
  $("release").onclick = () => act("robot.release").then(() => toast("STOP released: motions allowed again")).catch(() => {});
  window.addEventListener("keydown", onKey, true);
  window.addEventListener("keyup", onKey, true);
  $("stream-start").onclick = () => act("camera.stream.start").catch(() => {});
  $("stream-stop").onclick = () => act("camera.stream.stop").catch(() => {});
  $("view-width").onchange = sendView;
  $("view-fps").onchange = sendView;
  $("cam").onclick = zoomAt;
  $("zoom-reset").onclick = () => { S.view.roi = null; $("zoom-reset").disabled = true; sendView(); };
  $("capture").onclick = () => {
    const id = S.nextId++;
    S.calls.set(id, { resolve: (r) => toast(`saved ${r.saved} (robot: ${r.robot_path || "-"})`),
                      reject: (e) => toast(`capture: ${e.message}`) });
    send({ op: "capture", id, label: "console" });
  };
  $("tracker-aim").onclick = () => act("tracker.aim", { x: Number($("aim-x").value), y: Number($("aim-y").value),
                                                        z: Number($("aim-z").value) }).then(() => toast("aimed")).catch(() => {});
  $("tracker-find").onclick = () => act("tracker.find").then(() => { toast("found"); slowPoll(); }).catch(() => {});
  $("tracker-measure").onclick = () => act("tracker.measure").then((p) => {
    const sd = Array.isArray(p.std) ? Math.hypot(...p.std) : p.std;   // per-axis 1σ: their length
    $("tracker-point").textContent = `${fmt(p.x)}, ${fmt(p.y)}, ${fmt(p.z)} mm (measure, σ ${fmt(sd, 4)} mm)`;
    $("tracker-env").textContent = `${fmt(p.temperature_c, 1)} °C, ${fmt(p.pressure_mbar, 1)} mbar, ` +
      `${fmt(p.humidity_rh, 0)} % RH`;
    stamp("tracker-point-age", Date.now());
    stamp("tracker-env-age", Date.now());
  }).catch(() => {});
  $("proc-start").onclick = startJob;
  $("proc-cancel").onclick = () => S.job && act("calib.cancel", { job: S.job.job }).then(refreshJobs).catch(() => {});
  $("proc-resume").onclick = () => S.job && act("calib.resume", { job: S.job.job }).then(refreshJobs).catch(() => {});
}
document.addEventListener("DOMContentLoaded", () => { bind(); connect(); setInterval(markStale, 500); });
