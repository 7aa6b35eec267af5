// Live time series and the age of every shown value (uses S/$/fmt from console.js, axes from plots.js,
// el from dom.js). The console keeps the points (daemon/console/series.py) and sends each tab those it
// has not had; a point's `t` is the sample's time on this computer's clock, so now - t is its age.
"use strict";
const LIVE_WINDOW_S = 60;    // the plots' span: a motion and the pause after it
const LIVE_GAP_MS = 1500;    // a longer silence between two points is drawn as a gap, not a line
const AGE_OLD_MS = 3000;     // older values are marked: the robot.state and tracker sources tick faster
// one plot per quantity: its series, the value indexes in the series' `v`, the lines' colours
const LIVE_PLOTS = [
  { id: "live-x", series: "pose", lines: [0], title: "x (odometry)" },
  { id: "live-y", series: "pose", lines: [1], title: "y (odometry)" },
  { id: "live-heading", series: "pose", lines: [2], title: "heading (odometry)" },
  { id: "live-wheels", series: "wheels", lines: [0, 1], title: "wheel speeds" },
  { id: "live-tracker", series: "tracker", lines: [0], title: "tracker distance" },
];
const LINE_COLOURS = ["#1565c0", "#c62828"];
S.series = { pose: [], wheels: [], tracker: [] };
S.seriesSpec = {};   // series -> [[name, unit], ...], from the console's hello

function ageText(ms) {   // how long ago, in the unit that reads best
  if (!Number.isFinite(ms)) return "never";
  const s = Math.max(0, ms) / 1000;
  if (s < 10) return `${s.toFixed(1)} s ago`;
  if (s < 120) return `${s.toFixed(0)} s ago`;
  return s < 7200 ? `${(s / 60).toFixed(0)} min ago` : `${(s / 3600).toFixed(0)} h ago`;
}
function stamp(id, at) {   // an age beside a value: renderAges keeps it current
  const node = $(id);
  if (at === undefined || at === null) delete node.dataset.at; else node.dataset.at = String(at);
  renderAge(node, Date.now());
}
function renderAge(node, now) {
  const at = Number(node.dataset.at);
  node.textContent = node.dataset.at === undefined ? "" : `(${ageText(now - at)})`;
  node.classList.toggle("old", node.dataset.at !== undefined && now - at > AGE_OLD_MS);
}
function renderAges() {
  const now = Date.now();
  for (const node of document.querySelectorAll(".ago")) renderAge(node, now);
}

function addSeries(points) {   // from each state message: new points, oldest first
  const keepFrom = Date.now() - 2 * LIVE_WINDOW_S * 1000;
  for (const p of points || []) {
    const list = S.series[p.s];
    if (!list || !Array.isArray(p.v) || !Number.isFinite(p.t)) continue;   // unknown series: ignored
    list.push({ t: p.t, v: p.v.map((x) => (typeof x === "number" ? x : null)) });
  }
  for (const list of Object.values(S.series)) {
    while (list.length && list[0].t < keepFrom) list.shift();
  }
  if (points && points.length) showPose();
}
function latest(name) { const l = S.series[name]; return l.length ? l[l.length - 1] : null; }

function showPose() {   // the header's and the Robot panel's pose: the newest pose point, one text for both
  const p = latest("pose");
  if (!p) return;
  const [x, y, h] = p.v, text = `x ${fmt(x, 1)} mm, y ${fmt(y, 1)} mm, heading ${fmt(h, 2)}°`;
  $("robot-pose").textContent = text;
  $("pose-head").textContent = text;
  stamp("robot-pose-age", p.t);
  stamp("pose-head-age", p.t);
}

function buildLivePlots() {
  $("live-plots").replaceChildren(...LIVE_PLOTS.map((d) => el("figure", { className: "live", id: d.id },
    el("figcaption", {}, el("b", { textContent: d.title }), " ", el("span", { className: "now" }), " ",
       el("span", { className: "ago" })),
    el("canvas", { width: 420, height: 150 }))));
}
function unitOf(d) { return ((S.seriesSpec[d.series] || [])[d.lines[0]] || ["", ""])[1]; }
function drawLive() {
  const now = Date.now();
  for (const d of LIVE_PLOTS) {
    const fig = $(d.id), cv = fig.querySelector("canvas"), ctx = cv.getContext("2d");
    const pts = S.series[d.series].filter((p) => p.t >= now - LIVE_WINDOW_S * 1000);
    const last = latest(d.series), spec = S.seriesSpec[d.series] || [];
    const named = (i) => (d.lines.length > 1 ? `${(spec[i] || ["?"])[0]} ` : "");   // which wheel
    fig.querySelector(".now").textContent = last
      ? `${d.lines.map((i) => `${named(i)}${fmt(last.v[i], 1)}`).join(", ")} ${unitOf(d)}` : "–";
    const age = fig.querySelector(".ago");
    if (last) age.dataset.at = String(last.t); else delete age.dataset.at;
    renderAge(age, now);
    const ys = pts.flatMap((p) => d.lines.map((i) => p.v[i])).filter((v) => v !== null);
    const to = axes(ctx, cv.width, cv.height, [-LIVE_WINDOW_S, 0], ys.length ? ys : [0],
                    { xlabel: "s before now", ylabel: unitOf(d), pad: [54, 8, 8, 30] });
    if (!ys.length) {
      ctx.fillStyle = "#555"; ctx.fillText(`nothing in the last ${LIVE_WINDOW_S} s`, 64, 24);
      continue;
    }
    d.lines.forEach((i, k) => {
      ctx.strokeStyle = LINE_COLOURS[k]; ctx.lineWidth = 1.5; ctx.beginPath();
      let prev = null;
      for (const p of pts) {
        if (p.v[i] === null) { prev = null; continue; }
        const [X, Y] = to((p.t - now) / 1000, p.v[i]);
        if (prev !== null && p.t - prev < LIVE_GAP_MS) ctx.lineTo(X, Y); else ctx.moveTo(X, Y);
        ctx.fillStyle = LINE_COLOURS[k]; ctx.fillRect(X - 1.5, Y - 1.5, 3, 3);   // a short burst still shows
        prev = p.t;
      }
      ctx.stroke();
    });
    if (d.lines.length > 1) legend(ctx, cv.width, d.lines.map((i, k) =>
      ({ label: (spec[i] || ["?"])[0], colour: LINE_COLOURS[k] })));
  }
  S.liveDrawn = (S.liveDrawn || 0) + 1;
}
document.addEventListener("DOMContentLoaded", () => {
  buildLivePlots();
  setInterval(() => { drawLive(); renderAges(); }, 500);
});
