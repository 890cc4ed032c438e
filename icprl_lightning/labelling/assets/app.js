// The page's loop: fetch the annotator's pair, draw it, send the key pressed, show the next.
"use strict";
const params = new URLSearchParams(location.search);
const TOKEN = params.get("token") || "";
const KEYS = {"1": "first", "2": "second", "e": "equal", "s": "skip"};
let annotator = params.get("annotator") || localStorage.getItem("icprl-annotator") || "";
let shown = null, since = 0, busy = false;

function nonce() {
  const bytes = crypto.getRandomValues(new Uint8Array(16));
  return Array.from(bytes, b => b.toString(16).padStart(2, "0")).join("");
}

async function call(path, body) {
  const url = `${path}?token=${encodeURIComponent(TOKEN)}&annotator=${encodeURIComponent(annotator)}`;
  const response = await fetch(url, body === undefined ? {} :
    {method: "POST", headers: {"Content-Type": "application/json"}, body: JSON.stringify(body)});
  const payload = await response.json();
  if (!response.ok) throw new Error(payload.error || response.statusText);
  return payload;
}

function render(p) {
  shown = p;
  const [done, total] = p.progress;
  document.getElementById("fill").style.width = `${100 * done / total}%`;
  document.getElementById("count").textContent = `${done} / ${total}`;
  document.getElementById("status").textContent = "";
  if (p.done && p.waiting) {  // an online agent: its next question comes when it reaches its next query step
    document.getElementById("view").replaceChildren();
    document.getElementById("question").textContent = `${done} answered. Waiting for the agent's next question…`;
    document.getElementById("legend").textContent = "";
    setTimeout(async () => { if (!busy && shown === p) render(await call("/api/pair")); }, 300);
  } else if (p.done) {
    document.getElementById("view").replaceChildren();
    document.getElementById("question").textContent = `All ${total} pairs answered. Thank you.`;
    document.getElementById("legend").textContent = "";
  } else {
    document.getElementById("question").textContent = `Pair ${done + 1} of ${total}: which of the two is better?`;
    document.getElementById("legend").textContent = draw(p);
  }
  document.body.dataset.pair = p.done ? "done" : p.pair;
  document.body.dataset.done = String(done);
  since = performance.now();
}

async function press(key) {
  if (busy || shown === null) return;
  const label = KEYS[key];
  if (label === undefined && key !== "u") return;
  if (label !== undefined && shown.done) return;
  busy = true;
  try {
    render(key === "u" ? await call("/api/undo", {annotator, nonce: nonce()})
      : await call("/api/answer", {annotator, pair: shown.pair, label, nonce: nonce(),
                                    response_ms: Math.round(performance.now() - since)}));
  } catch (e) {
    document.getElementById("status").textContent = e.message;
    try { render(await call("/api/pair")); } catch (_) { /* the status says why */ }
  } finally {
    busy = false;
  }
}

async function start() {
  while (!/^[A-Za-z0-9_-]{1,40}$/.test(annotator)) {
    annotator = (prompt("Your name (letters, digits, - or _):") || "").trim();
  }
  localStorage.setItem("icprl-annotator", annotator);
  document.getElementById("who").textContent = annotator;
  document.addEventListener("keydown", e => { if (!e.repeat) press(e.key.toLowerCase()); });
  for (const b of document.querySelectorAll("button")) b.addEventListener("click", () => press(b.dataset.key));
  render(await call("/api/pair"));
}
start();
