// The commissioning's view ("checks", ritactl commission): its table of checks in the Commissioning panel,
// one row per check with its verdict, device, name, the measured value and why. Every cell is the daemon's
// text: built with el() (dom.js), never parsed as markup. procedures.js calls showChecks(r.checks) for such
// a result; the result panel keeps its verdict and messages, the table is shown here only.
"use strict";

const CHECK_CLASS = { pass: "ok", fail: "bad", warn: "warn", skip: "skip" };

function showChecks(checks) {
  const td = (...c) => el("td", {}, ...c);
  const head = el("tr", {}, ...["verdict", "device", "check", "measured", "detail"].map((h) => el("th", { textContent: h })));
  const rows = checks.map((c) => el("tr", { dataset: { check: `${c.device}.${c.name}`, verdict: c.verdict } },
    td(el("span", { className: `pill ${CHECK_CLASS[c.verdict] || ""}`, textContent: String(c.verdict).toUpperCase() })),
    td(c.device), td(c.name), td(c.value), td(c.detail || "")));
  const n = (v) => checks.filter((c) => c.verdict === v).length;
  $("result-table").replaceChildren();
  $("commission-report").replaceChildren(
    el("table", { className: "paper checks" }, el("thead", {}, head), el("tbody", {}, ...rows)),
    el("p", { textContent: `${n("pass")} passed, ${n("fail")} failed, ${n("warn")} warned, ${n("skip")} skipped` }));
  $("commission-panel").hidden = false;
}
