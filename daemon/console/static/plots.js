// Plain-canvas plots of the Rita console: axes with ticks, labels and units, equal aspect for positions, legends.
"use strict";

function niceTicks(lo, hi, n = 5) {   // round tick values covering [lo, hi]: steps of 1, 2 or 5 × 10^k
  const span = (hi - lo) || Math.abs(hi) || 1, raw = span / n, k = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 5, 10].map((m) => m * k).find((s) => s >= raw) || raw;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) out.push(Math.abs(v) < step * 1e-9 ? 0 : v);
  return { ticks: out, digits: Math.max(0, -Math.floor(Math.log10(step))) };
}

// Ticks for a time axis (s since the epoch, UTC): a step from seconds to weeks whose labels show that
// step's resolution, so two ticks never read the same ("MM-DD HH:MM" five times over one minute did).
const TIME_STEPS_S = [1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600, 43200,
                      86400, 172800, 604800, 1209600, 2592000];
function timeTicks(lo, hi, n = 5) {
  const raw = Math.max(hi - lo, 1) / n, step = TIME_STEPS_S.find((s) => s >= raw) || raw;
  const iso = (v) => new Date(v * 1000).toISOString();
  const fmt = step < 60 ? (v) => iso(v).slice(11, 19)                   // HH:MM:SS
    : step < 86400 ? (v) => iso(v).slice(5, 16).replace("T", " ")       // MM-DD HH:MM
      : (v) => iso(v).slice(0, 10);                                     // YYYY-MM-DD
  const ticks = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9; v += step) ticks.push(v);
  return { ticks, fmt };
}

// o: {title, xlabel, ylabel, equal (same mm per pixel on both axes), xfmt (tick text),
//     xtime (the x values are UTC seconds: timeTicks), pad ([left, right, top, bottom] margins in px)};
// returns data -> pixel
function axes(ctx, w, h, xs, ys, o) {
  const [L, R, T, B] = o.pad || [62, 14, 26, 40], pw = w - L - R, ph = h - T - B;
  let x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  if (x1 === x0) { x0 -= 1; x1 += 1; }
  if (y1 === y0) { y0 -= 1; y1 += 1; }
  const padX = (x1 - x0) * 0.08, padY = (y1 - y0) * 0.08;
  x0 -= padX; x1 += padX; y0 -= padY; y1 += padY;
  let sx = pw / (x1 - x0), sy = ph / (y1 - y0);
  if (o.equal) {   // one scale for both: widen the tighter axis around its centre
    const s = Math.min(sx, sy), cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
    sx = sy = s; x0 = cx - pw / s / 2; x1 = cx + pw / s / 2; y0 = cy - ph / s / 2; y1 = cy + ph / s / 2;
  }
  const to = (x, y) => [L + (x - x0) * sx, T + ph - (y - y0) * sy];
  ctx.clearRect(0, 0, w, h); ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  ctx.strokeStyle = "#999"; ctx.lineWidth = 1; ctx.strokeRect(L, T, pw, ph);
  ctx.font = "11px sans-serif"; ctx.fillStyle = "#333";
  const xt = o.xtime ? timeTicks(x0, x1) : niceTicks(x0, x1), yt = niceTicks(y0, y1);
  const xfmt = o.xtime ? xt.fmt : o.xfmt || ((v) => v.toFixed(xt.digits));
  S.lastTicks = { x: xt.ticks.map(xfmt), y: yt.ticks.map((v) => v.toFixed(yt.digits)) };   // tests read them
  ctx.textAlign = "center"; ctx.textBaseline = "top";
  for (const v of xt.ticks) {
    const [X] = to(v, y0);
    ctx.strokeStyle = "#eee"; ctx.beginPath(); ctx.moveTo(X, T); ctx.lineTo(X, T + ph); ctx.stroke();
    ctx.strokeStyle = "#666"; ctx.beginPath(); ctx.moveTo(X, T + ph); ctx.lineTo(X, T + ph + 4); ctx.stroke();
    ctx.fillText(xfmt(v), X, T + ph + 6);
  }
  ctx.textAlign = "right"; ctx.textBaseline = "middle";
  for (const v of yt.ticks) {
    const [, Y] = to(x0, v);
    ctx.strokeStyle = "#eee"; ctx.beginPath(); ctx.moveTo(L, Y); ctx.lineTo(L + pw, Y); ctx.stroke();
    ctx.strokeStyle = "#666"; ctx.beginPath(); ctx.moveTo(L - 4, Y); ctx.lineTo(L, Y); ctx.stroke();
    ctx.fillText(v.toFixed(yt.digits), L - 6, Y);
  }
  ctx.textAlign = "left"; ctx.textBaseline = "alphabetic"; ctx.font = "12px sans-serif";
  if (o.title) ctx.fillText(o.title, L, T - 9);
  ctx.textAlign = "center"; ctx.fillText(o.xlabel || "", L + pw / 2, h - 4);
  ctx.save(); ctx.translate(12, T + ph / 2); ctx.rotate(-Math.PI / 2); ctx.fillText(o.ylabel || "", 0, 0); ctx.restore();
  ctx.textAlign = "left";
  return to;
}

function legend(ctx, w, items) {   // [{label, colour}] in a box at the plot's top right
  ctx.font = "11px sans-serif";
  const width = 16 + Math.max(...items.map((i) => ctx.measureText(i.label).width)), x = w - 14 - width - 6, y = 30;
  ctx.fillStyle = "#fffe"; ctx.strokeStyle = "#bbb"; ctx.fillRect(x, y, width + 6, items.length * 14 + 6);
  ctx.strokeRect(x, y, width + 6, items.length * 14 + 6);
  items.forEach((it, i) => {
    ctx.fillStyle = it.colour; ctx.beginPath(); ctx.arc(x + 8, y + 10 + i * 14, 4, 0, 7); ctx.fill();
    ctx.fillStyle = "#333"; ctx.textBaseline = "middle"; ctx.fillText(it.label, x + 16, y + 10 + i * 14);
  });
  ctx.textBaseline = "alphabetic";
}

const headingColour = (deg) => `hsl(${((deg % 360) + 360) % 360},80%,45%)`;
