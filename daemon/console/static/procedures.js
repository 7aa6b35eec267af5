// Procedures, results and history panels of the Rita console (uses call/act/S/$ from console.js).
// Job ids, procedures, states, messages, file and dataset names are the daemon's data: built as elements
// (dom.js el) or through esc(), never spliced into markup as they came.
"use strict";

function rel(path) {  // a robot path under its data dir, as files.read wants it
  if (!path) return "";
  return S.dataDir && path.startsWith(S.dataDir + "/") ? path.slice(S.dataDir.length + 1) : path;
}
function pathUrl(path) {  // a data-dir path as a URL path: each name percent-encoded (`#`, `?` and `"` too)
  return rel(path).split("/").map(encodeURIComponent).join("/");
}
function fileLink(path, text) {  // an <a> element downloading a data-dir file
  const href = `/files/${pathUrl(path)}?download=1`;
  return el("a", { href, download: "", textContent: text || rel(path) });
}
function datasetLink(dataset, text) {  // the dataset's listing in a new tab
  return el("a", { href: `/list/${pathUrl(dataset)}`, target: "_blank", textContent: text });
}
// what a procedure's result shows (daemon/bus/procedures.py: pose, camera_model, mark, clusters)
const viewOf = (procedure) => ((S.procInfo || {})[procedure] || {}).view;
async function ensureDataDir() {  // links name data-dir paths: know the data dir before drawing any (reload, 2nd tab)
  if (!S.dataDir) S.dataDir = (await call("data.dir", {}, 5)).data_dir;
}
async function fetchJson(path) {
  const resp = await fetch(`/files/${pathUrl(path)}`);
  if (!resp.ok) throw new Error(`${path}: HTTP ${resp.status}`);
  return resp.json();
}

async function refreshJobs() {
  let r;
  try { await ensureDataDir(); r = await call("calib.jobs", {}, 5); } catch (e) { return; }
  S.jobs = r.jobs || [];   // not its latch: robot.latch telemetry is the page's one latch state (robot.js)
  // follow the newest job, wherever it was started (a second tab, ritactl), unless the operator picked one from the list
  if (S.jobs.length && (!S.job || !S.pinned)) S.job = S.jobs[S.jobs.length - 1];
  const mine = S.job && S.jobs.find((j) => j.job === S.job.job);
  if (mine) { S.job = mine; showJob(mine); }
  showJobs(S.jobs);
  followJobs();   // robot.js: a job that drives closes the motion dialog and disables Move…/Turn…
}
function showJobs(jobs) {   // the last eight jobs, each a link that pins the job panel to it
  const items = jobs.slice(-8).map((j, i) => {
    const pick = (ev) => {
      ev.preventDefault(); S.pinned = true; S.job = j; S.shownResult = null; showJob(j);
    };
    const link = el("a", { href: "#", dataset: { job: j.job }, textContent: j.job, onclick: pick });
    return [i ? " · " : "", link, ` ${j.procedure} ${j.state}`];
  });
  $("jobs").replaceChildren("jobs: ", ...items.flat());
}

function showJob(j) {
  $("job-id").textContent = j.job;
  $("job-state").textContent = `${j.procedure || ""} ${j.state}${j.error ? ": " + j.error : ""}`;
  const p = j.progress || {};
  $("job-progress").value = j.state === "done" ? 100 : (p.percent || 0);
  $("job-step").textContent = p.step ? `${p.step}${p.waiting_for ? " (" + p.waiting_for + ")" : ""}` : "";
  showPrompt(j);
  if (j.state === "done" && j.result && S.shownResult !== j.job) { S.shownResult = j.job; showResult(j.result); }
  if (j.state !== "done") $("result").hidden = true;
  applyRole();
}

function showPrompt(j) {
  const box = $("prompt");
  if (j.state !== "waiting" || !j.prompt) { box.hidden = true; box.dataset.job = ""; return; }
  if (box.dataset.job === j.job && box.dataset.q === j.prompt.question) return;
  box.dataset.job = j.job; box.dataset.q = j.prompt.question;
  S.promptsSeen = (S.promptsSeen || 0) + 1;
  $("prompt-question").textContent = j.prompt.question;
  const choices = $("prompt-choices");
  choices.replaceChildren();
  for (const c of j.prompt.choices || []) {
    const b = document.createElement("button");
    b.textContent = c; b.id = `prompt-choice-${c}`; b.dataset.cmd = "calib.answer";
    b.onclick = () => act("calib.answer", { job: j.job, answer: c }).then(() => { box.hidden = true; refreshJobs(); }).catch(() => {});
    choices.appendChild(b);
  }
  box.hidden = false;
  applyRole();
}

function showResult(r) {
  $("result").hidden = false;
  $("result-verdict").textContent = r.verdict;
  $("result-verdict").className = r.verdict === "ok" ? "pill ok" : "pill bad";
  const u = r.uncertainty || {};
  if (r.rob_H_cam) {
    const m = r.rob_H_cam.map((row) => row.map((v) => fmt(v, 6).padStart(12)).join(" ")).join("\n");
    $("result-rob-H-cam").textContent = `rob_H_cam =\n${m}\n1σ translation (mm): ${(u.std_t_mm || []).map((v) => fmt(v, 4)).join(", ")}` +
      `\n1σ rotation (°): ${(u.std_rot_deg || []).map((v) => fmt(v, 4)).join(", ")}`;
  } else $("result-rob-H-cam").textContent = r.mark ? `mark (ACS, mm): ${r.mark.abs_xyz.map((v) => fmt(v)).join(", ")}` : "";
  $("result-messages").replaceChildren(...(r.messages || []).map((t) => el("li", { textContent: t })));
  $("result-table").innerHTML = markdownTable(r.table_markdown || "");
  if (viewOf(r.procedure) === "checks" && r.checks) showChecks(r.checks);   // checks.js
  if (viewOf(r.procedure) === "camera_model" && r.dataset) showIntrinsics(r.dataset);
  const names = ["result.json", "result.yaml", ...(r.files || [])];
  const files = names.flatMap((f) => [" ", fileLink(`${r.dataset}/${f}`, f)]);
  const listing = r.dataset ? datasetLink(r.dataset, rel(r.dataset)) : null;
  $("result-files").replaceChildren(...(r.dataset ? ["dataset ", listing, ":", ...files] : []));
  plotResult(r);
  refreshResults();
}

async function showIntrinsics(dataset) {  // f, principal point, RMS and σ at a glance (from the stored result)
  let m;
  try { m = (await fetchJson(`${dataset}/result.json`)).camera_model; } catch (e) { toast(e.message); return; }
  const K = m.K, sd = m.std || {}, cal = m.calibration || {};
  $("result-rob-H-cam").textContent = `f ${fmt(K[0][0], 2)} / ${fmt(K[1][1], 2)} px (1σ ${fmt(sd.fx, 2)} / ${fmt(sd.fy, 2)}), ` +
    `principal point ${fmt(K[0][2], 1)}, ${fmt(K[1][2], 1)} px (1σ ${fmt(sd.cx, 2)}, ${fmt(sd.cy, 2)}), ` +
    `RMS ${fmt(cal.rms_px, 3)} px over ${cal.n_views ?? "?"} views`;
}
function markdownTable(text) {  // the paper's table (a Markdown pipe table) as HTML; other lines as text
  // escaped first (dom.js esc), then the only markup: **bold** and *italic*, around text already escaped
  const inline = (t) => esc(t).replace(/\*\*(.+?)\*\*/g, "<b>$1</b>").replace(/\*(.+?)\*/g, "<i>$1</i>");
  const out = [];
  let rows = [];
  const flush = () => {
    if (!rows.length) return;
    const cells = (l) => l.trim().replace(/^\||\|$/g, "").split("|").map((c) => inline(c.trim()));
    const body = rows.filter((l) => !/^\s*\|?\s*:?-{2,}/.test(l)).map(cells);
    out.push("<table class=\"paper\"><thead><tr>" + body[0].map((c) => `<th>${c}</th>`).join("") + "</tr></thead><tbody>" +
      body.slice(1).map((r) => "<tr>" + r.map((c) => `<td>${c}</td>`).join("") + "</tr>").join("") + "</tbody></table>");
    rows = [];
  };
  for (const line of text.split("\n")) {
    if (line.trim().startsWith("|")) rows.push(line);
    else { flush(); if (line.trim()) out.push(`<p>${inline(line)}</p>`); }
  }
  flush();
  return out.join("");
}

// ------------------------------------------------------------------ plots (plots.js draws the axes)
async function plotResult(r) {
  const cv = $("result-plot"), ctx = cv.getContext("2d");
  if (viewOf(r.procedure) === "clusters" && r.dataset) {   // the cluster plot: every mark, coloured by approach heading
    let full;
    try { full = await fetchJson(`${r.dataset}/result.json`); } catch (e) { toast(e.message); return; }
    const pts = full.marks.map((m) => [m.abs_xyz[0], m.abs_xyz[1], m.heading_deg]);
    const mx = pts.reduce((a, p) => a + p[0], 0) / pts.length, my = pts.reduce((a, p) => a + p[1], 0) / pts.length;
    const xs = pts.map((p) => (p[0] - mx) * 1000), ys = pts.map((p) => (p[1] - my) * 1000);
    const to = axes(ctx, cv.width, cv.height, xs, ys, { title: "every mark around their mean (ACS)", equal: true,
                                                         xlabel: "x − mean (µm)", ylabel: "y − mean (µm)" });
    pts.forEach((p, i) => { const [X, Y] = to(xs[i], ys[i]); ctx.fillStyle = headingColour(p[2]);
      ctx.beginPath(); ctx.arc(X, Y, 4, 0, 7); ctx.fill(); });
    const norm = (h) => ((Math.round(h / 5) * 5) % 360 + 360) % 360;   // a direction to the nearest 5°, 0–355
    const headings = [...new Set(pts.map((p) => norm(p[2])))].sort((a, b) => a - b);
    legend(ctx, cv.width, headings.map((h) => ({ label: `approach ${h}°`, colour: headingColour(h) })));
    return;
  }
  if (r.rob_H_cam) {   // referencing: the camera's position in the robot frame with its 1σ, x-y and z bars
    const t = [r.rob_H_cam[0][3], r.rob_H_cam[1][3], r.rob_H_cam[2][3]];
    const s = (r.uncertainty || {}).std_t_mm || [0, 0, 0];
    const k = 3;   // axes of ±3σ around the estimate
    const to = axes(ctx, cv.width, cv.height, [t[0] - k * s[0] - 1e-3, t[0] + k * s[0] + 1e-3],
                    [t[1] - k * s[1] - 1e-3, t[1] + k * s[1] + 1e-3],
                    { title: "camera position in the robot frame, 1σ ellipse", equal: true, xlabel: "x (mm)", ylabel: "y (mm)" });
    const [X, Y] = to(t[0], t[1]), [X1, Y1] = to(t[0] + s[0], t[1] + s[1]);
    ctx.strokeStyle = "#1565c0"; ctx.lineWidth = 2; ctx.beginPath();
    ctx.ellipse(X, Y, Math.abs(X1 - X) || 2, Math.abs(Y1 - Y) || 2, 0, 0, 7); ctx.stroke();
    ctx.fillStyle = "#c62828"; ctx.beginPath(); ctx.arc(X, Y, 4, 0, 7); ctx.fill();
    ctx.fillStyle = "#333"; ctx.textAlign = "right"; ctx.fillText(`z ${fmt(t[2])} ± ${fmt(s[2], 4)} mm`, cv.width - 16, 40);
    ctx.textAlign = "left";
  }
}

async function refreshResults() {
  let r;
  try { await ensureDataDir(); r = await call("calib.results", {}, 10); } catch (e) { return; }
  const a = r.active;
  $("calib-active").replaceChildren(...(a
    ? [`active calibration: job ${a.job} (${a.created}), verdict ${a.verdict}, `,
       fileLink(`${a.dataset}/result.yaml`, "result.yaml")]
    : ["no active calibration"]));
  const td = (...c) => el("td", {}, ...c);
  $("history").replaceChildren(el("table", {}, ...r.history.slice(0, 30).map((h) => el("tr", {},
    td(h.created || ""), td(h.job ?? ""), td(h.procedure ?? ""), td(h.verdict ?? h.error ?? ""),
    td(h.dataset ? fileLink(`${h.dataset}/result.json`, "result.json") : ""),
    td(h.dataset ? datasetLink(h.dataset, "dataset") : "")))));
  const refs = r.history.filter((h) => viewOf(h.procedure) === "pose" && h.job).slice(0, 40).reverse();
  const series = [];
  for (const h of refs) {
    try { const full = await fetchJson(`calibration/history/${h.job}.json`); if (full.rob_H_cam) series.push(full); } catch (e) { /* skip */ }
  }
  drawDrift(series);
}
function drawDrift(series) {   // rob_H_cam translation over time: drift between referencings
  const cv = $("drift-plot"), ctx = cv.getContext("2d");
  if (!series.length) { ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, cv.width, cv.height); ctx.fillStyle = "#333"; ctx.fillText("no referencing yet", 20, 20); return; }
  const t = series.map((s) => Date.parse(s.created) / 1000);
  const d = ["#c62828", "#2e7d32", "#1565c0"].map((c, i) => ({ c, v: series.map((s) => (s.rob_H_cam[i][3] - series[0].rob_H_cam[i][3]) * 1000) }));
  const to = axes(ctx, cv.width, cv.height, t.length > 1 ? t : [t[0] - 1, t[0] + 1], d.flatMap((x) => x.v).concat([0]),
                  { title: "rob_H_cam translation relative to the first referencing", xlabel: "time (UTC)", ylabel: "µm",
                    xtime: true });
  S.driftTicks = S.lastTicks;   // what the x axis reads: tests check its labels differ
  legend(ctx, cv.width, d.map(({ c }, i) => ({ label: "xyz"[i], colour: c })));
  for (const { c, v } of d) {
    ctx.strokeStyle = c; ctx.beginPath();
    v.forEach((y, i) => { const [X, Y] = to(t[i], y); i ? ctx.lineTo(X, Y) : ctx.moveTo(X, Y); ctx.fillStyle = c; ctx.fillRect(X - 2, Y - 2, 4, 4); });
    ctx.stroke();
  }
}
document.addEventListener("DOMContentLoaded", () => setTimeout(refreshResults, 1500));
