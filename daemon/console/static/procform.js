// The procedure's parameter form, built from the console's hello (`procedure_params`: the table in
// daemon/bus/procedures.py, the one the worker takes its defaults from). The page checks what it can and
// names the field; the console checks again (it never trusts the page) and reads the chosen robot files.
"use strict";

function fieldId(name, i) { return `pp-${name}${i === undefined ? "" : "-" + i}`; }

// the input element(s) of one parameter, as HTML: every value from the hello goes through esc()
function paramInput(p) {
  const title = esc(`${p.help}${p.range ? "; range " + p.range : ""}${p.unit ? " " + p.unit : ""}`);
  const shown = esc(p.default === null || p.default === undefined ? "" : String(p.default));
  const hint = esc(p.default_text || (p.required ? "required" : ""));
  const id = (i) => esc(fieldId(p.name, i));
  if (p.kind === "bool") {
    return `<input type="checkbox" id="${id()}" class="ctl" title="${title}"${p.default ? " checked" : ""}>`;
  }
  if (p.choices.length) {
    return `<select id="${id()}" class="ctl" title="${title}">` +
      p.choices.map((c) => `<option${c === p.default ? " selected" : ""}>${esc(c)}</option>`).join("") +
      "</select>";
  }
  if (p.kind === "vec") {
    return `<span class="vec">` + [...Array(p.length).keys()].map((i) =>
      `<input id="${id(i)}" class="ctl" size="7" inputmode="decimal" title="${title}" ` +
      `placeholder="${"xyz"[i]}${p.required ? " (required)" : ""}">`).join("") + "</span>";
  }
  if (p.kind === "file") {
    return `<input id="${id()}" class="ctl" size="28" list="robot-json" ` +
      `title="${title}; a data-dir path on the robot" ` +
      `placeholder="${p.installed ? esc(p.installed) + " (installed)" : hint}">`;
  }
  return `<input id="${id()}" class="ctl" size="8" inputmode="decimal" title="${title}" value="${shown}" ` +
    `placeholder="${hint}">`;
}

function renderProcForm() {
  const params = (S.procParams || {})[$("proc").value] || [];
  $("proc-form").dataset.procedure = $("proc").value;
  $("proc-form").innerHTML = params.map((p) =>
    `<label class="field" data-param="${esc(p.name)}"><span>${esc(p.name)}${p.required ? " *" : ""}` +
    `${p.unit ? " (" + esc(p.unit) + ")" : ""}</span>` +
    `${paramInput(p)}</label>`).join("");
  $("proc-error").textContent = "";
  if (S.role !== "unknown") applyRole();
  fillRobotFiles();
}

async function fillRobotFiles() {   // the file choices: JSON definitions on the robot (not datasets or history)
  if (S.robotFiles) return;
  S.robotFiles = [];
  try {
    const r = await call("files.list", {}, 15);
    S.robotFiles = r.files.map((f) => f.path).filter((p) => p.endsWith(".json") && !/^(procedures|calibration\/history)\//.test(p));
  } catch (e) { S.robotFiles = null; return; }   // try again at the next render
  // file names are the robot's data: option elements with the name as their value, never markup
  $("robot-json").replaceChildren(...S.robotFiles.map((p) => el("option", { value: p })));
}

function checkNumber(p, text) {   // a number inside the parameter's range, or throws naming the field
  const v = Number(text);
  if (text.trim() === "" || !Number.isFinite(v)) throw { field: p.name, message: `${p.name}: ${JSON.stringify(text)} is not a number` };
  if (p.kind === "int" && !Number.isInteger(v)) throw { field: p.name, message: `${p.name}: ${text} is not an integer` };
  const low = p.lo !== null && (p.lo_open ? v <= p.lo : v < p.lo), high = p.hi !== null && v > p.hi;
  if (low || high) throw { field: p.name, message: `${p.name}: ${v} is outside ${p.range}${p.unit ? " " + p.unit : ""}` };
  return v;
}

function formValue(p) {   // the parameter's value from the form; undefined: left to the worker's default
  if (p.kind === "bool") return $(fieldId(p.name)).checked;
  if (p.kind === "vec") {
    const texts = [...Array(p.length).keys()].map((i) => $(fieldId(p.name, i)).value.trim());
    if (texts.every((t) => t === "")) return undefined;
    return texts.map((t) => checkNumber(p, t));
  }
  const text = $(fieldId(p.name)).value.trim();
  if (text === "") return undefined;
  return p.kind === "float" || p.kind === "int" ? checkNumber(p, text) : text;
}

function collectParams() {   // {params} or throws {field, message}
  const params = {};
  for (const p of (S.procParams || {})[$("proc").value] || []) {
    const v = formValue(p);
    if (v === undefined && p.required) throw { field: p.name, message: `${p.name} is required (${p.help})` };
    if (v !== undefined) params[p.name] = v;
  }
  const extra = $("proc-params").value.trim();   // advanced: a JSON object merged over the form
  if (extra) {
    let more;
    try { more = JSON.parse(extra); } catch (e) { throw { field: "", message: `advanced parameters are not JSON: ${e.message}` }; }
    if (typeof more !== "object" || more === null || Array.isArray(more)) throw { field: "", message: "advanced parameters must be a JSON object" };
    Object.assign(params, more);
  }
  return params;
}

function showParamError(e) {
  for (const el of document.querySelectorAll("#proc-form .bad-field")) el.classList.remove("bad-field");
  $("proc-error").textContent = e ? e.message : "";
  const label = e && e.field && document.querySelector(`#proc-form [data-param="${CSS.escape(e.field)}"]`);
  if (label) { label.classList.add("bad-field"); const input = label.querySelector("input, select"); if (input) input.focus(); }
}

async function startJob() {
  let params;
  try { params = collectParams(); } catch (e) { showParamError(e); return; }
  showParamError(null);
  try {
    const r = await call("calib.start", { procedure: $("proc").value, params }, 60);
    S.job = { job: r.job, state: "queued" };
    S.shownResult = null;
    showJob(S.job);
    refreshJobs();
  } catch (e) { showParamError(e); }   // the console's own check names the field too
}
document.addEventListener("DOMContentLoaded", () => { $("proc").onchange = renderProcForm; });
