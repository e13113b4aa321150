// The shadowless operator console. No build step, no libraries.
// Every piece of rig data is put on the page with textContent or setAttribute, never as HTML.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const HISTORY_S = 600;
let csrf = "";
let events = null;
let history = [];
let snap = null;
const rows = new Map();          // slot -> {tr, cells, gainInput, gainError, thumbImg, thumbAge, nodeState}

const $ = (id) => document.getElementById(id);

function el(tag, attrs, text) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  if (text !== undefined && text !== null) e.textContent = String(text);
  return e;
}

function svgEl(tag, attrs, text) {
  const e = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, String(v));
  if (text !== undefined && text !== null) e.textContent = String(text);
  return e;
}

function clear(node) { while (node.firstChild) node.removeChild(node.firstChild); }

function fmt(x, digits) {
  if (x === null || x === undefined || Number.isNaN(x)) return "–";
  return typeof x === "number" ? x.toFixed(digits === undefined ? 1 : digits) : String(x);
}

function ago(unix) {
  const s = Math.max(0, Date.now() / 1000 - unix);
  if (s < 90) return `${Math.round(s)} s ago`;
  if (s < 5400) return `${Math.round(s / 60)} min ago`;
  return `${(s / 3600).toFixed(1)} h ago`;
}

// ------------------------------------------------------------------ talking to the coordinator
async function api(path, options) {
  const opts = Object.assign({ credentials: "same-origin", headers: {} }, options || {});
  if ((opts.method || "GET") === "POST") opts.headers["X-CSRF-Token"] = csrf;
  const resp = await fetch(path, opts);
  let body = {};
  try { body = await resp.json(); } catch (e) { body = { ok: false, error: `HTTP ${resp.status}` }; }
  if (!resp.ok || body.ok === false) {
    const err = new Error(body.error || `HTTP ${resp.status}`);
    err.status = resp.status;
    err.retryAfter = resp.headers.get("Retry-After");
    throw err;
  }
  return body;
}

function postJSON(path, doc) {
  return api(path, { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(doc) });
}

// Run an action: disable its button, show its error beside it (the log shows it too).
async function act(button, errorEl, fn) {
  errorEl.textContent = "";
  button.disabled = true;
  try {
    await fn();
  } catch (e) {
    errorEl.textContent = e.message;
    if (e.status === 401) showLogin("Your session ended: log in again.");
  } finally {
    button.disabled = false;
  }
}

// ------------------------------------------------------------------ login
function showLogin(message) {
  if (events) { events.close(); events = null; }
  stopThumbs();
  csrf = "";
  $("main-view").hidden = true;
  $("logout").hidden = true;
  $("who").textContent = "";
  $("conn").textContent = "not connected";
  $("conn").classList.remove("ok");
  $("login-view").hidden = false;
  $("login-error").textContent = message || "";
  $("login-name").focus();
}

function showMain(who, role) {
  $("login-view").hidden = true;
  $("main-view").hidden = false;
  $("logout").hidden = false;
  applyRole(who, role);      // people.js: the name and role, a viewer's page
  connect();
  startThumbs();
}

async function login(ev) {
  ev.preventDefault();
  const button = $("login-button");
  button.disabled = true;
  $("login-error").textContent = "";
  try {
    const r = await postJSON("/login", loginBody());
    $("token").value = "";
    csrf = r.csrf;
    showMain(r.who, r.role);
  } catch (e) {
    let msg = e.message;
    if (e.status === 429 && e.retryAfter) msg += ` (retry after ${e.retryAfter} s)`;
    $("login-error").textContent = msg;
  } finally {
    button.disabled = false;
  }
}

async function logout() {
  try { await api("/logout", { method: "POST" }); } catch (e) { /* ended anyway */ }
  showLogin("Logged out.");
}

// ------------------------------------------------------------------ the event stream
function connect() {
  if (events) events.close();
  events = new EventSource("/api/events");
  events.addEventListener("open", () => { $("conn").textContent = "live"; $("conn").classList.add("ok"); });
  events.addEventListener("error", async () => {
    $("conn").textContent = "reconnecting…";
    $("conn").classList.remove("ok");
    if (events && events.readyState === EventSource.CLOSED) {
      try { await api("/api/session"); setTimeout(connect, 1000); }
      catch (e) { showLogin("Your session ended: log in again."); }
    }
  });
  events.addEventListener("snapshot", (e) => { snap = JSON.parse(e.data); render(snap); });
  events.addEventListener("history", (e) => { history = JSON.parse(e.data); drawPlots(); });
  events.addEventListener("sample", (e) => {
    history.push(JSON.parse(e.data));
    if (history.length > HISTORY_S) history.splice(0, history.length - HISTORY_S);
    drawPlots();
  });
}

// ------------------------------------------------------------------ rendering
function render(s) {
  $("rig-name").textContent = `${s.rig.name} (${s.rig.id})`;
  $("showing").textContent = s.showing || "nothing";
  const sh = s.show;
  // only a show that is on (a stopped one is history: the line would sit beside every later still)
  const on = ["scheduled", "playing", "paused"].includes(sh.state);
  $("show-state").textContent = on ? `show ${sh.state}: ${sh.name || (sh.asset_id || "").slice(0, 12)}` : "";
  const y = s.sync;
  $("sync-line").textContent = `skew p50 ${fmt(y.skew_p50_ms, 2)} ms, p99 ${fmt(y.skew_p99_ms, 2)} ms over ` +
    `${y.frames} frames (${y.skew_source || "no frames yet"}); late ${y.frames_late}, dropped ${y.frames_dropped}`;
  renderNodes(s.slots);
  renderRefusals(s.refusals);
  renderLogins(s.logins);
  renderBeforeAuth(s.before_auth);
  renderAssets(s.assets);
  renderActions(s.actions);
  renderJob(s.job);
  // other scripts of the page (blend.js) follow the snapshot too
  document.dispatchEvent(new CustomEvent("rig-snapshot", { detail: s }));
}

function renderNodes(slots) {
  const tbody = $("nodes").tBodies[0];
  const seen = new Set();
  for (const n of slots) {
    seen.add(n.slot);
    let r = rows.get(n.slot);
    if (!r) { r = makeRow(n.slot); rows.set(n.slot, r); }
    tbody.appendChild(r.tr);          // keeps the coordinator's order
    const c = r.cells;
    c.state.textContent = n.state;
    c.state.className = `state state-${n.state}`;
    r.tr.setAttribute("data-state", n.state);
    r.nodeState = n.node_state;
    c.host.textContent = n.host ? `${n.host} (pid ${n.pid})` : "–";
    c.host.title = [n.output, n.gl, n.decoder && `video decoder ${n.decoder}`, n.software && `shadowless ${n.software}`].filter(Boolean).join(" · ");
    c.offset.textContent = fmt(n.clock_offset_ms, 1);
    c.drift.textContent = fmt(n.clock_drift_ppm, 1);
    c.rtt.textContent = fmt(n.clock_rtt_ms, 1);
    c.shown.textContent = n.frames_shown;
    c.late.textContent = n.frames_late;
    c.dropped.textContent = n.frames_dropped;
    c.assets.textContent = `${n.assets_ready}/${n.assets_wanted}`;
    if (document.activeElement !== r.gainInput && !r.gainInput.dataset.dirty && n.gain !== null) {
      r.gainInput.value = String(n.gain);
    }
    c.refusal.textContent = n.refusal ? `${n.refusal.reason} (${n.refusal.count}×, ${ago(n.refusal.at)})` : "";
  }
  for (const [slot, r] of rows) {
    if (!seen.has(slot)) { r.tr.remove(); rows.delete(slot); }
  }
}

function makeRow(slot) {
  const tr = el("tr", { "data-slot": slot });
  const cells = {};
  const add = (name, cls) => { const td = el("td", cls ? { class: cls } : {}); tr.appendChild(td); cells[name] = td; return td; };
  add("slot").textContent = slot;
  add("state", "state");
  const thumbTd = add("thumb", "thumb");
  const thumbImg = el("img", { class: "thumb-img", alt: `what ${slot} shows`, hidden: "" });
  const thumbAge = el("span", { class: "thumb-age" }, "");
  thumbTd.append(thumbImg, thumbAge);
  add("host");
  for (const k of ["offset", "drift", "rtt", "shown", "late", "dropped"]) add(k, "num");
  add("assets", "num");
  const gainTd = add("gain");
  const input = el("input", { class: "gain", type: "number", min: "0", max: "16", step: "0.05",
                              "aria-label": `gain of ${slot}` });
  input.addEventListener("input", () => { input.dataset.dirty = "1"; });
  const button = el("button", { type: "button", class: "gain-set" }, "Set");
  const err = el("span", { class: "error", role: "alert" });
  button.addEventListener("click", () => act(button, err, async () => {
    await postJSON("/api/gain", { slot, gain: input.value === "" ? null : Number(input.value) });
    delete input.dataset.dirty;
  }));
  gainTd.append(input, button, err);
  add("refusal", "reason");
  observeThumb(slot, tr);
  return { tr, cells, gainInput: input, gainError: err, thumbImg, thumbAge, nodeState: "", thumbBusy: false };
}

// ------------------------------------------------------------------ thumbnails
// What each projector shows, fetched about once a second for the rows on screen while the page is
// visible: fetching one is what makes the coordinator ask that node for pictures, so a closed or
// hidden page costs the rig nothing. The PNG becomes a data: URL (the page's CSP allows no blob:).
const THUMB_EVERY_MS = 1000;
const thumbsOnScreen = new Set();
let thumbObserver = null;
let thumbTimer = null;

function observeThumb(slot, tr) {
  if (!("IntersectionObserver" in window)) { thumbsOnScreen.add(slot); return; }
  if (!thumbObserver) {
    thumbObserver = new IntersectionObserver((entries) => {
      for (const e of entries) {
        const s = e.target.getAttribute("data-slot");
        if (e.isIntersecting) thumbsOnScreen.add(s); else thumbsOnScreen.delete(s);
      }
    });
  }
  thumbObserver.observe(tr);
}

function dataURL(blob) {
  return new Promise((resolve, reject) => {
    const reader = new FileReader();
    reader.onload = () => resolve(reader.result);
    reader.onerror = () => reject(reader.error);
    reader.readAsDataURL(blob);
  });
}

async function refreshThumb(slot, r) {
  if (r.thumbBusy) return;
  r.thumbBusy = true;
  try {
    const resp = await fetch(`/api/thumbnail/${encodeURIComponent(slot)}`, { credentials: "same-origin", cache: "no-store" });
    if (!resp.ok) {
      let msg = `HTTP ${resp.status}`;
      try { msg = (await resp.json()).error || msg; } catch (e) { /* not JSON */ }
      if (r.thumbImg.hidden) r.thumbAge.textContent = "no picture yet";
      r.thumbAge.title = msg;
      return;
    }
    const frame = resp.headers.get("X-Frame-Id") || "";
    const age = Number(resp.headers.get("X-Age-Ms"));
    const url = await dataURL(await resp.blob());
    if (!rows.has(slot)) return;
    r.thumbImg.src = url;
    r.thumbImg.hidden = false;
    r.thumbImg.dataset.frame = frame;
    r.thumbImg.dataset.age = String(age);
    r.thumbAge.textContent = `${fmt(age / 1000, 1)} s old`;
    r.thumbAge.title = `frame ${frame}, as of ${new Date(Date.now() - age).toLocaleTimeString()}`;
  } catch (e) {
    r.thumbAge.textContent = "not reachable";
  } finally {
    r.thumbBusy = false;
  }
}

function refreshThumbs() {
  if (document.visibilityState !== "visible" || $("main-view").hidden) return;
  for (const [slot, r] of rows) {
    if (thumbsOnScreen.has(slot) && r.nodeState && r.nodeState !== "expected") refreshThumb(slot, r);
  }
}

function startThumbs() {
  if (!thumbTimer) thumbTimer = setInterval(refreshThumbs, THUMB_EVERY_MS);
}

function stopThumbs() {
  if (thumbTimer) { clearInterval(thumbTimer); thumbTimer = null; }
}

function renderRefusals(list) {
  const tbody = $("refusals").tBodies[0];
  clear(tbody);
  if (!list.length) { tbody.appendChild(el("tr")).appendChild(el("td", { colspan: "5", class: "muted" }, "none")); return; }
  for (const r of list) {
    const tr = el("tr");
    tr.append(el("td", {}, r.peer), el("td", {}, r.slot || "–"), el("td", { class: "num" }, r.count),
              el("td", {}, ago(r.at)), el("td", { class: "reason" }, r.reason));
    tbody.appendChild(tr);
  }
}

function renderLogins(l) {
  const p = $("logins");
  if (!l || !l.failed) { p.textContent = "console logins: no wrong token since the coordinator started"; return; }
  let text = `console logins: ${l.failed} wrong token${l.failed === 1 ? "" : "s"} since the coordinator started ` +
    `(last ${ago(l.last_failed_at)}), ${l.refused} refused while a limit held`;
  if (l.held_back) {
    text += ` — more than ${l.budget_per_min} a minute from many addresses: addresses that failed now wait their ` +
      "turn; browsers that logged in here before, like this one, are not held back";
  }
  p.textContent = text;
  p.className = l.held_back ? "warn" : "muted";
}

// Calls from peers that have not proved the rig token: what the budget refused or could not parse.
function renderBeforeAuth(a) {
  const p = $("before-auth");
  if (!a) { p.textContent = ""; return; }
  const budget = `budget ${a.max_calls} calls and ${a.max_mib} MiB in all, ${a.max_calls_per_address} calls and ` +
    `${a.max_mib_per_address} MiB per address`;
  if (!a.refused && !a.malformed) {
    p.textContent = `calls before login: none refused since the coordinator started (${budget})`;
    p.className = "muted";
    return;
  }
  p.textContent = `calls before login: ${a.refused} refused over the budget, ${a.malformed} malformed, ` +
    `${a.waited} waited their turn since the coordinator started; peak ${a.peak_mib} MiB held (${budget})`;
  p.className = "warn";
}

function renderAssets(list) {
  const sel = $("asset");
  const keep = sel.value;
  const key = JSON.stringify(list.map((a) => a.id));
  if (sel.dataset.key === key) return;
  sel.dataset.key = key;
  clear(sel);
  if (!list.length) sel.appendChild(el("option", { value: "" }, "no assets (shadowless content add)"));
  for (const a of list) {
    sel.appendChild(el("option", { value: a.id }, `${a.name || "(unnamed)"} — ${a.kind}, ${a.frames} frames, ${a.id.slice(0, 12)}`));
  }
  if (list.some((a) => a.id === keep)) sel.value = keep;
}

function renderActions(list) {
  const tbody = $("actions").tBodies[0];
  clear(tbody);
  for (const a of list) {
    const tr = el("tr", a.ok ? {} : { class: "failed" });
    const params = Object.keys(a.params || {}).length ? JSON.stringify(a.params) : "";
    tr.append(el("td", {}, a.time.replace("T", " ").replace("+00:00", " UTC")), el("td", {}, a.who),
              el("td", {}, a.address), el("td", {}, a.action), el("td", { class: "reason" }, params),
              el("td", { class: "reason" }, `${a.ok ? "ok" : "refused"}: ${a.result}`));
    tbody.appendChild(tr);
  }
}

// ------------------------------------------------------------------ jobs
let jobOptions = null;

function fieldInput(f) {
  // One form control per job option; only what the operator changes is sent (defaults live in the job).
  const id = `job-opt-${f.name}`;
  let input;
  if (f.kind === "bool") {
    input = el("input", { id, type: "checkbox" });
    input.checked = !!f.default;
  } else if (f.kind === "choice") {
    input = el("select", { id });
    input.appendChild(el("option", { value: "" }, f.default === null ? "(default)" : `(default: ${f.default})`));
    for (const c of f.choices) input.appendChild(el("option", { value: String(c) }, String(c)));
  } else if (f.kind === "int" || f.kind === "float") {
    input = el("input", { id, type: "number", step: f.kind === "int" ? "1" : "any",
                          placeholder: f.default === null ? "" : String(f.default) });
    if (f.lo !== null) input.setAttribute("min", String(f.lo));
    if (f.hi !== null) input.setAttribute("max", String(f.hi));
  } else {
    const ph = f.default === null ? "" : (Array.isArray(f.default) ? f.default.join(f.kind === "pair" ? "x" : ",") : String(f.default));
    input = el("input", { id, type: "text", spellcheck: "false", placeholder: ph });
  }
  input.dataset.kind = f.kind;
  input.dataset.name = f.name;
  input.dataset.initial = f.kind === "bool" ? String(!!f.default) : "";
  const helpId = `${id}-help`;
  input.setAttribute("aria-describedby", helpId);
  const label = el("label", { for: id, class: "opt-label" }, fieldLabel(f));
  const wrap = el("div", { class: "job-field", "data-option": f.name });
  if (f.kind === "bool") {
    label.prepend(input);          // a checkbox sits before its label
    wrap.append(label);
  } else {
    wrap.append(label, input);
  }
  const hint = fieldHint(f);
  const help = el("p", { id: helpId, class: "opt-help" }, f.help || "");
  if (hint) help.prepend(el("span", { class: "opt-range" }, hint + " · "));
  wrap.appendChild(help);
  return wrap;
}

// "Settle (s)": the option's own label (the server derives one from the name where none is declared)
function fieldLabel(f) {
  return f.label || f.name;
}

// What the value may be: its range with the unit, and the default ("0–30 s · default 0.1").
function fieldHint(f) {
  const unit = f.unit ? ` ${f.unit}` : "";
  const parts = [];
  if (f.lo !== null && f.lo !== undefined && f.hi !== null && f.hi !== undefined) parts.push(`${f.lo}–${f.hi}${unit}`);
  else if (f.lo !== null && f.lo !== undefined) parts.push(`at least ${f.lo}${unit}`);
  else if (f.hi !== null && f.hi !== undefined) parts.push(`at most ${f.hi}${unit}`);
  else if (f.unit) parts.push(`in ${f.unit}`);
  if (f.kind !== "bool" && f.default !== null && f.default !== undefined && f.default !== "" &&
      !(Array.isArray(f.default) && !f.default.length)) {
    const d = Array.isArray(f.default) ? f.default.join(f.kind === "pair" ? "×" : ", ") : String(f.default);
    parts.push(`default ${d}${unit}`);
  } else if (f.kind === "bool") {
    parts.push(f.default ? "on unless unticked" : "off unless ticked");
  }
  return parts.join(" · ");
}

function renderJobFields() {
  const box = $("job-fields");
  clear(box);
  const fields = jobOptions && jobOptions[$("job-kind").value];
  if (!fields) return;
  if (fields.unavailable) { box.appendChild(el("p", { class: "error" }, fields.unavailable)); return; }
  const groups = new Map();
  for (const f of fields) {
    if (!groups.has(f.group)) groups.set(f.group, []);
    groups.get(f.group).push(f);
  }
  for (const [g, list] of groups) {
    const fs = el("fieldset", {});
    fs.appendChild(el("legend", {}, g || "options"));
    for (const f of list) fs.appendChild(fieldInput(f));
    box.appendChild(fs);
  }
}

function jobParams() {
  // The options the operator set, as JSON values; a value that does not parse is refused here.
  const params = {};
  for (const input of $("job-fields").querySelectorAll("[data-name]")) {
    const k = input.dataset.kind, name = input.dataset.name;
    if (k === "bool") { if (String(input.checked) !== input.dataset.initial) params[name] = input.checked; continue; }
    const v = input.value.trim();
    if (v === "") continue;
    if (k === "int" || k === "float") params[name] = Number(v);
    else if (k === "list") params[name] = v.split(",").map((s) => s.trim()).filter((s) => s);
    else if (k === "pair") params[name] = v.split(/[x,]/).map((s) => Number(s.trim()));
    else if (k === "json") {
      try { params[name] = JSON.parse(v); } catch (e) { params[name] = v; }   // a path or a name stays text
    } else params[name] = v;
  }
  return params;
}

async function loadJobOptions(kinds) {
  const sel = $("job-kind");
  if (sel.options.length === 0) for (const k of kinds) sel.appendChild(el("option", { value: k }, k));
  if (jobOptions === null) {
    jobOptions = {};
    try { jobOptions = await api("/api/job/options"); } catch (e) { $("job-error").textContent = e.message; }
    renderJobFields();
  }
}

function renderJob(job) {
  if (snap && snap.job_kinds) loadJobOptions(snap.job_kinds);
  const line = $("job-line"), bar = $("job-progress"), logEl = $("job-log");
  if (!job) { line.textContent = "no job has run since the coordinator started"; bar.hidden = true; logEl.textContent = ""; return; }
  const eta = job.eta_s === null ? "" : `, about ${Math.round(job.eta_s)} s left in this stage`;
  const stage = job.stage ? `${job.stage}${job.item ? " (" + job.item + ")" : ""}: ${job.done}/${job.total}` : "starting";
  if (job.state === "running") {
    line.textContent = `${job.kind} running, ${Math.round(job.elapsed_s)} s — ${stage}${eta}`;
  } else {
    const how = job.state === "failed" ? `failed: ${job.error}` : job.state;
    line.textContent = `${job.kind} ${how} after ${Math.round(job.elapsed_s)} s`;
  }
  line.className = `job-line job-${job.state}`;
  bar.hidden = !(job.state === "running" && job.total > 0);
  if (job.total > 0) { bar.max = job.total; bar.value = job.done; }
  logEl.textContent = (job.message ? job.message + "\n" : "") + job.log.join("\n");
  $("job-cancel").disabled = job.state !== "running";
}

// ------------------------------------------------------------------ plots
function niceMax(v) {
  if (!(v > 0)) return 1;
  const p = Math.pow(10, Math.floor(Math.log10(v)));
  for (const k of [1, 2, 2.5, 5, 10]) if (v <= k * p) return k * p;
  return 10 * p;
}

function drawChart(svg, series, yLabel) {
  clear(svg);
  const W = 640, H = 200, L = 56, R = 12, T = 22, B = 36;
  const now = history.length ? history[history.length - 1].t : Date.now() / 1000;   // the coordinator's clock
  const span = Math.max(60, Math.min(HISTORY_S, history.length ? now - history[0].t : 60));
  let ymax = 0;
  for (const s of series) for (const p of history) { const v = p[s.key]; if (v !== null && v > ymax) ymax = v; }
  ymax = niceMax(ymax);
  const X = (t) => L + (W - L - R) * (1 - (now - t) / span);
  const Y = (v) => T + (H - T - B) * (1 - v / ymax);
  for (let i = 0; i <= 4; i++) {
    const v = (ymax * i) / 4;
    svg.appendChild(svgEl("line", { class: "grid", x1: L, x2: W - R, y1: Y(v), y2: Y(v) }));
    svg.appendChild(svgEl("text", { x: L - 6, y: Y(v) + 4, "text-anchor": "end" }, +v.toPrecision(3)));
  }
  for (let i = 0; i <= 5; i++) {
    const t = now - (span * i) / 5;
    svg.appendChild(svgEl("text", { x: X(t), y: H - B + 14, "text-anchor": "middle" },
                          i === 0 ? "now" : `−${Math.round(span * i / 5)}`));
  }
  svg.appendChild(svgEl("line", { class: "axis", x1: L, x2: L, y1: T, y2: H - B }));
  svg.appendChild(svgEl("line", { class: "axis", x1: L, x2: W - R, y1: H - B, y2: H - B }));
  svg.appendChild(svgEl("text", { x: (L + W - R) / 2, y: H - 4, "text-anchor": "middle" }, "time (s before now)"));
  svg.appendChild(svgEl("text", { x: 14, y: (T + H - B) / 2, "text-anchor": "middle",
                                  transform: `rotate(-90 14 ${(T + H - B) / 2})` }, yLabel));
  series.forEach((s, i) => {
    let pts = [];
    const flush = () => {
      if (pts.length > 1) svg.appendChild(svgEl("polyline", { class: `line s${i}`, points: pts.join(" ") }));
      pts = [];
    };
    for (const p of history) {
      const v = p[s.key];
      if (v === null || v === undefined || now - p.t > span) { flush(); continue; }
      pts.push(`${X(p.t).toFixed(1)},${Y(v).toFixed(1)}`);
    }
    flush();
    svg.appendChild(svgEl("rect", { class: `s${i}`, x: L + 10 + i * 120, y: 6, width: 10, height: 10 }));
    svg.appendChild(svgEl("text", { x: L + 24 + i * 120, y: 15 }, s.label));
  });
}

function drawPlots() {
  drawChart($("plot-skew"), [{ key: "skew_p50_ms", label: "skew p50" }, { key: "skew_p99_ms", label: "skew p99" },
                             { key: "clock_error_ms", label: "clock error" }], "ms");
  drawChart($("plot-late"), [{ key: "late", label: "late frames" }], "late frames per s");
}

// ------------------------------------------------------------------ wiring
document.addEventListener("DOMContentLoaded", async () => {
  $("login-form").addEventListener("submit", login);
  $("logout").addEventListener("click", logout);
  // Stop and Blackout ask first: confirm.js; the layout is drawn by layout.js, the health banner by health.js
  $("identify").addEventListener("click",
    () => act($("identify"), $("stop-error"), () => api("/api/identify", { method: "POST" })));
  $("show-form").addEventListener("submit", (ev) => {
    ev.preventDefault();
    const form = new FormData($("show-form"));
    act($("show-button"), $("show-error"), () => api("/api/show", { method: "POST", body: form }));
  });
  $("play-form").addEventListener("submit", (ev) => {
    ev.preventDefault();
    act($("play-button"), $("play-error"),
        () => postJSON("/api/play", { asset: $("asset").value, loop: $("loop").checked }));
  });
  $("job-kind").addEventListener("change", renderJobFields);
  document.addEventListener("visibilitychange", refreshThumbs);
  $("job-form").addEventListener("submit", (ev) => {
    ev.preventDefault();
    act($("job-start"), $("job-error"), () => postJSON("/api/job", { kind: $("job-kind").value, params: jobParams() }));
  });
  $("job-cancel").addEventListener("click",
    () => act($("job-cancel"), $("job-error"), () => api("/api/job/cancel", { method: "POST" })));
  try {
    const r = await api("/api/session");
    csrf = r.csrf;
    showMain(r.who, r.role);
  } catch (e) {
    showLogin("");
  }
});
