// Plate survey panel: `ritactl plate survey` run by the console on this laptop (daemon/console/survey.py).
// The paths are the laptop's; the state (progress, report, error) comes with the state messages when it changes.
"use strict";

function startSurvey() {
  const fields = { folder: $("survey-folder").value, plate: $("survey-plate").value, out: $("survey-out").value };
  const empty = Object.entries({ folder: "photo folder", plate: "design file", out: "output file" }).find(([k]) => !fields[k].trim());
  if (empty) { $("survey-message").textContent = `${empty[1]}: give a path on this computer`; return; }
  $("survey-message").textContent = "starting…";
  request({ op: "survey", action: "start", ...fields }, "plate survey", 30)
    .catch((e) => { $("survey-message").textContent = `plate survey: ${e.message}`; });
}

function showSurvey(s) {
  S.survey = s;
  if (s.state === "running") S.surveySteps = (S.surveySteps || 0) + 1;   // progress updates seen (tests)
  const running = s.state === "running";
  $("survey-start").dataset.busy = running ? "1" : "";   // applyRole keeps a busy control disabled
  $("survey-start").disabled = running || !allowed("calib.start");   // an operator's control, as on the robot
  $("survey-cancel").disabled = !running || !allowed("calib.start");
  $("survey-progress").value = s.state === "done" ? 100 : (s.percent || 0);
  $("survey-step").textContent = running ? s.step : (s.state === "idle" ? "" : `${s.state}${s.took_s ? ", " + s.took_s + " s" : ""}`);
  const r = s.result;
  $("survey-message").className = s.state === "failed" ? "err" : "";
  if (s.state === "done" && r) {
    // the verdict, nest names, photo names and reasons come from the survey's report: elements, not markup
    $("survey-message").replaceChildren(el("b", { className: `pill ${r.verdict === "ok" ? "ok" : "bad"}`,
                                                  textContent: r.verdict }),
                                        ` ${r.message}; wrote `, el("code", { textContent: s.out }));
    const td = (text) => el("td", { textContent: text });
    $("survey-nests").replaceChildren(
      el("tr", {}, ...["nest", "seat x, y, z (mm, PCS)", "1σ x, y, z (µm)", "photos"]
        .map((h) => el("th", { textContent: h }))),
      ...Object.entries(r.nests).map(([c, n]) => el("tr", {}, td(c),
        td(n.ref_P_nst_mm.map((v) => fmt(v, 3)).join(", ")),
        td(n.sigma_mm.map((v) => fmt(v * 1000, 0)).join(", ")), td(n.views))));
    const lines = r.views.map((v) => `${v.image}: ${v.corners} corners, RMS ${fmt(v.corner_rms_px, 3)} px` +
      (Object.keys(v.rings_missing || {}).length
        ? `; missing ${Object.keys(v.rings_missing).join(", ")}` : ""))
      .concat(Object.entries(r.skipped || {}).map(([n, why]) => `${n}: skipped, ${why}`));
    $("survey-views").replaceChildren(...lines.flatMap((t, i) => (i ? [el("br"), t] : [t])));
  } else {
    if (s.state !== "idle") $("survey-message").textContent = running ? `surveying ${s.folder}` : s.message;
    if (running) { $("survey-nests").replaceChildren(); $("survey-views").replaceChildren(); }
  }
}
function uploadPlate() {   // the output file (on this laptop) to calibration/NAME on the robot; referencing then names it
  $("survey-uploaded").textContent = "sending…";
  request({ op: "survey", action: "upload", out: $("survey-out").value, name: $("survey-name").value }, "plate upload", 30)
    .then((r) => {
      const kept = r.replaced ? `; the previous one kept as ${r.replaced}` : "";
      $("survey-uploaded").textContent = `${r.unchanged ? "already on the robot" : "stored on the robot"} as ${r.path}${kept}`;
      S.robotFiles = null;   // the referencing form offers it from now on
      fillRobotFiles();
      if ($("pp-plate")) $("pp-plate").value = r.path;   // the chosen procedure takes a plate
      toast(`plate stored as ${r.path}`);
    })
    .catch((e) => { $("survey-uploaded").textContent = `plate upload: ${e.message}`; });
}

document.addEventListener("DOMContentLoaded", () => {
  $("survey-start").onclick = startSurvey;
  $("survey-upload").onclick = uploadPlate;
  $("survey-cancel").onclick = () => request({ op: "survey", action: "cancel" }, "plate survey", 10).catch((e) => toast(e.message));
});
