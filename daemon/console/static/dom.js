// The console's one way to put text from the daemon into the page. Every string the robot sends (file
// names, job ids, labels, reasons, error messages, plate and nest names, health fields) is data, never
// markup: a data-dir file named `x"><img onerror=...>.json` must show as that name, not run.
// Rule: set such text with textContent or build elements with el(); where a few lines of markup are
// clearer, every daemon value in them goes through esc() (element text and quoted attributes alike).
"use strict";

const ESCAPES = { "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;", "`": "&#96;" };
function esc(value) { return String(value ?? "").replace(/[&<>"'`]/g, (c) => ESCAPES[c]); }

// el("a", {href: url, textContent: name, dataset: {job: id}}, child, "text", ...): an element built
// without parsing markup; props are element properties (textContent, className, title, onclick, ...),
// `dataset` entries and `attrs` (setAttribute), children nodes or strings (as text).
function el(tag, props = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(props)) {
    if (k === "dataset") Object.assign(node.dataset, v);
    else if (k === "attrs") for (const [a, av] of Object.entries(v)) node.setAttribute(a, String(av));
    else node[k] = v;
  }
  for (const c of children) if (c !== null && c !== undefined && c !== false) node.append(c);
  return node;
}
