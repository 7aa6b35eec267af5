// The robot as the page shows and drives it (uses S/$/call/act/toast/el from console.js and dom.js).
// One robot state for the Robot and Daemon panels: both render robotSummary(), from the base's status
// (robot.state), its device in the daemon (daemon.health) and the latched STOP (robot.latch), so the
// two can never say different things. Motions follow the latch and the jobs that drive: the Move…/Turn…
// buttons are disabled while either holds, an open confirmation closes when a STOP latches or such a
// job appears, and a confirmed motion is checked again against the daemon's own state before it is sent.
"use strict";
const ACTIVE_JOB_STATES = ["queued", "running", "waiting"];   // the daemon's: a STOP stops these jobs
S.latchEpoch = 0;          // latch engagements this page has seen: a dialog opened before one never sends
S.latchSince = undefined;  // since_ns of the last engagement counted
S.motions = [];            // what each Move…/Turn… ended as: sent, or why not (tests read it)
let motionDialog = null;   // the open confirmation: {end(why)}

// ------------------------------------------------------------------ one state for both panels
function robotSummary() {   // {text, cls} from the current sources, or null when none is current
  const now = Date.now(), fresh = (src, panel) => now - (S.fresh[src] || -Infinity) <= SOURCES[panel][1];
  const dev = fresh("daemon.health", "daemon-panel") ? S.robotDevice : null;
  const base = fresh("robot.state", "robot-panel") ? S.robotBase : null;
  let text, cls;
  if (dev && !["READY", "BUSY"].includes(dev.state)) {   // the daemon lost the base: its last status is old
    text = `${dev.state}${dev.reason ? ` (${dev.reason})` : ""}`; cls = dev.state;
  } else if (base) {
    text = `${base.state}${base.fault ? ` (${base.fault})` : ""}`; cls = base.state;
  } else return null;
  if (S.latch && S.latch.latched) { text += " · STOP latched"; cls = "LATCHED"; }
  return { text, cls };
}
function renderRobotState() {   // the Robot panel's state and the Daemon panel's robot row, one text
  const s = robotSummary();
  if (s) S.robotShown = s.text;
  const text = s ? s.text : (S.robotShown ? `unknown (was ${S.robotShown})` : "?");
  for (const node of [$("robot-state"), ...document.querySelectorAll("[data-robot-state]")]) {
    node.textContent = text;
    node.className = `st st-${s ? s.cls : "unknown"}`;
  }
}

// ------------------------------------------------------------------ latch and driving jobs
function drivingJob(jobs) {   // an active job of a procedure that drives (unknown procedures count)
  return (jobs || []).find((j) => ACTIVE_JOB_STATES.includes(j.state)
    && ((S.procInfo || {})[j.procedure] || {}).moves !== false);
}
function motionBlocked() {   // why the page may not send a motion now, or ""
  if (!S.latch) return "the STOP latch's state is not known yet";
  if (S.latch.latched) return "the STOP is latched: no motion until Release";
  const j = drivingJob(S.jobs);
  return j ? `job ${j.job} (${j.procedure}) drives the robot` : "";
}
function noteLatch(l) {   // every latch message, latest value or event: a new engagement ends open dialogs
  if (!l || !l.latched || l.since_ns === S.latchSince) return;
  S.latchSince = l.since_ns;
  S.latchEpoch += 1;
  closeMotionDialog("STOP latched: the motion dialog was closed, nothing was sent");
}
function showLatch(l) {   // the latched STOP, plainly: who, since when; Release for an operator
  S.latch = l;
  noteLatch(l);
  $("release").hidden = !l.latched;
  $("latch").classList.toggle("latched", !!l.latched);   // always shown: released is a state too
  if (l.latched) {
    const since = l.since_ns ? new Date(l.since_ns / 1e6).toLocaleTimeString() : "?";
    $("latch").textContent = `STOPPED (latched by ${l.by} at ${since})`;
    $("latch").title = `no motion until Release${l.reason ? `; reason: ${l.reason}` : ""}`;
  } else {
    $("latch").textContent = "STOP not latched";
    $("latch").title = "the latched STOP: while it holds, ritad refuses every motion";
  }
  renderRobotState();
  applyRole();
}
function followJobs() {   // after each calib.jobs: a job that drives ends the dialog, disables Move…/Turn…
  const j = drivingJob(S.jobs);
  if (j) closeMotionDialog(`job ${j.job} (${j.procedure}) drives the robot: the motion dialog was closed`);
  applyRole();
}
function gateMotions() {   // applyRole's last word on the controls that send a motion
  const why = motionBlocked();
  for (const b of document.querySelectorAll("[data-motion]")) if (why) b.disabled = true;
  $("motion-note").textContent = why && S.latch ? `Move…/Turn… disabled: ${why}` : "";
}

// ------------------------------------------------------------------ the confirmation dialog
function confirmMotion(text) {   // resolves "" when confirmed, else why not
  closeMotionDialog("");
  return new Promise((resolve) => {
    const epoch = S.latchEpoch;
    const d = { end: (why) => {
      if (motionDialog !== d) return;
      motionDialog = null;
      $("confirm").hidden = true;
      $("confirm-yes").onclick = $("confirm-no").onclick = null;
      resolve(why);
    } };
    motionDialog = d;
    $("confirm-text").textContent = text;
    $("confirm-yes").onclick = () => d.end(S.latchEpoch !== epoch ? "a STOP latched after the dialog opened"
                                                                 : motionBlocked());
    $("confirm-no").onclick = () => d.end("not confirmed");
    $("confirm").hidden = false;
    applyRole();
  });
}
function closeMotionDialog(why) {
  if (!motionDialog) return;
  motionDialog.end(why || "closed");
  if (why) toast(why);
}
async function recheck(epoch) {   // at the click, the daemon's own latch and jobs: the page's may lag
  if (S.latchEpoch !== epoch) return "a STOP latched after the dialog opened";
  let now;
  try {
    now = await call("calib.jobs", {}, 5);
  } catch (e) { return `the latch's state is unknown: ${e.message}`; }
  if (S.latchEpoch !== epoch) return "a STOP latched after the dialog opened";
  if (!now.latch || now.latch.latched) return "the STOP is latched: no motion until Release";
  const j = drivingJob(now.jobs);
  return j ? `job ${j.job} (${j.procedure}) drives the robot` : "";
}
async function move(kind) {   // Move… / Turn…: confirm, check again, send; resolves what happened
  const done = (outcome) => { S.motions.push({ kind, outcome }); return outcome; };
  const blocked = motionBlocked();
  if (blocked) { toast(`robot.${kind} not sent: ${blocked}`); return done(blocked); }
  const mm = Number($("move-mm").value), deg = Number($("turn-deg").value);
  const speed = Number($("move-speed").value);
  const turnRate = 20;  // robot.turn's default rate (°/s)
  const text = kind === "move"
    ? `Drive ${mm < 0 ? "BACKWARDS" : "forwards"} ${Math.abs(mm)} mm at ${speed} mm/s ` +
      `(about ${fmt(Math.abs(mm) / speed, 1)} s)?`
    : `Turn ${deg < 0 ? "clockwise" : "counter-clockwise"} ${Math.abs(deg)}° at ${turnRate}°/s ` +
      `(about ${fmt(Math.abs(deg) / turnRate, 1)} s)?`;
  const epoch = S.latchEpoch;
  const refused = (await confirmMotion(text)) || (await recheck(epoch));
  if (refused) {
    if (refused !== "not confirmed" && refused !== "closed") toast(`robot.${kind} not sent: ${refused}`);
    return done(refused);
  }
  const args = kind === "move" ? { distance_mm: mm, speed_mm_s: speed, confirm: true, wait: false }
                               : { angle_deg: deg, confirm: true, wait: false };
  act(`robot.${kind}`, args).catch(() => {});
  return done("sent");
}
document.addEventListener("DOMContentLoaded", () => {
  $("robot-move").onclick = () => { S.lastMotion = move("move"); };
  $("robot-turn").onclick = () => { S.lastMotion = move("turn"); };
});
