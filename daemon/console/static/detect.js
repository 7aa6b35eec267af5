// Detection overlay: on demand (Detect, or "every 3 s"), ritad's camera.detect runs the product's own detector
// on the newest frame; the page draws the answer (sensor pixels) over whatever view or zoom it shows.
// One request at a time from a page; the robot also runs one at a time (busy). docs/operations.md, "Operator console".
"use strict";
const DETECT_PERIOD_MS = 3000;   // "every 3 s": a full-frame search takes ~1 s of one robot core (docs/operations.md)
S.detection = null; S.detections = 0; S.detectBusy = false;

function detectSummary(d) {
  const where = `frame ${d.frame_id}, searched ${d.searched_w}×${d.searched_h}, ${fmt(d.took_s, 2)} s on the robot`;
  if (d.target === "plate") return `${d.n} corners (plate ${d.plate_id}; ${where})`;
  return d.found ? `${d.target} at ${fmt(d.uv[0], 1)}, ${fmt(d.uv[1], 1)} px (${where})` : `no ${d.target}: ${d.message}`;
}
function drawDetection(ctx, meta) {
  const d = S.detection;
  if (!d || !meta || !$("detect-show").checked) return;
  const at = (uv) => [(uv[0] + 0.5 - meta.x) / meta.step - 0.5, (uv[1] + 0.5 - meta.y) / meta.step - 0.5];
  if (d.target === "plate") {
    ctx.fillStyle = "#00e676";
    for (const uv of d.uv) { const [x, y] = at(uv); ctx.fillRect(x - 2, y - 2, 5, 5); }
  } else if (d.found) {
    const [x, y] = at(d.uv);
    ctx.strokeStyle = "#ffea00"; ctx.lineWidth = 2; ctx.beginPath();
    ctx.moveTo(x - 12, y); ctx.lineTo(x + 12, y); ctx.moveTo(x, y - 12); ctx.lineTo(x, y + 12); ctx.stroke();
  }
}
async function detect() {
  if (S.detectBusy) return;
  S.detectBusy = true; $("detect").dataset.busy = "1"; applyRole();
  const target = $("detect-target").value, width = Number($("detect-width").value);
  const args = { target, ...(width ? { width } : {}), ...(target === "plate" ? { plate_file: $("detect-plate").value } : {}) };
  try {
    S.detection = await call("camera.detect", args, 60);
    S.detections += 1;
    $("detect-info").textContent = detectSummary(S.detection);
    drawDetection($("cam").getContext("2d"), S.meta);   // at once, over the frame shown; later frames redraw it
  } catch (e) {
    S.detection = null;
    $("detect-info").textContent = `detect: ${e.message} [${e.code}]`;
  } finally {
    S.detectBusy = false; delete $("detect").dataset.busy; applyRole();
  }
}
function autoDetect() {
  if ($("detect-auto").checked && S.meta) detect();
  setTimeout(autoDetect, DETECT_PERIOD_MS);
}
document.addEventListener("DOMContentLoaded", () => { $("detect").onclick = detect; setTimeout(autoDetect, DETECT_PERIOD_MS); });
