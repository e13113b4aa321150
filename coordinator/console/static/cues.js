// The cue panel: the show's cue list with the current and the next cue, GO (the big button, or the
// space bar while the panel has focus), Back, a jump to any cue (click its row), and the list's
// editing: add, edit, remove, move up and down, each cue's fade and auto-follow.
// The state comes with every snapshot (key "cues", the same object as GET /api/cues); each change
// sends the whole list (POST /api/cues), which the coordinator checks and stores or refuses in one
// line, nothing stored. Its own scope, beside console.js (loaded first), whose helpers ($, el,
// clear, fmt, ago, api, postJSON, act) it uses; every value is put on the page with textContent.
(() => {
  "use strict";

  const PATTERNS = ["white", "grid", "crosshair", "bars"];
  const KIND_TEXT = { still: "still", asset: "asset", blackout: "blackout", pattern: "pattern" };
  let state = null;               // the last cue state: {cues, current, next, fired_at, fading, follow_at}
  let assets = [];                // names of the rig's assets, for the target field's suggestions

  function cuesOf(st) {
    if (!st) return [];
    return Array.isArray(st.cues) ? st.cues : (st.cues && st.cues.cues) || [];
  }

  function describe(c) {
    if (c.kind === "blackout") return "blackout";
    return `${KIND_TEXT[c.kind] || c.kind}: ${c.target}`;
  }

  function seconds(v) {
    return v === null || v === undefined ? "" : `${fmt(v, v % 1 ? 1 : 0)} s`;
  }

  // ------------------------------------------------------------------ showing the state
  let drawn = "";                 // the state the table shows (redrawn only when it changes)

  function render(st) {
    state = st;
    const cues = cuesOf(st);
    const key = JSON.stringify([cues, st.current, st.next, st.fading]);
    if (key !== drawn) { drawn = key; drawTable(st, cues); }
    renderLine(st, cues);
  }

  function drawTable(st, cues) {
    const tbody = $("cues").tBodies[0];
    clear(tbody);
    cues.forEach((c, k) => {
      const now = st.current === k, next = st.next === k;
      const tr = el("tr", { "data-id": c.id, "data-index": k, class: now ? "cue-current" : next ? "cue-next" : "",
                            title: `jump to cue ${c.id}: fire it now` });
      const mark = now ? (st.fading ? "now (fading)" : "now") : next ? "next" : "";
      const buttons = el("td", { class: "cue-row-actions" });
      const button = (label, title, fn) => {
        const b = el("button", { type: "button", title, class: `cue-${label.toLowerCase()}` }, label);
        b.addEventListener("click", (ev) => { ev.stopPropagation(); fn(); });
        buttons.appendChild(b);
      };
      button("Up", "move this cue up", () => move(k, -1));
      button("Down", "move this cue down", () => move(k, +1));
      button("Edit", "edit this cue in the form below", () => edit(k));
      button("Remove", "remove this cue from the list", () => remove(k));
      tr.append(el("td", { class: "cue-mark" }, mark), el("td", {}, c.id), el("td", {}, c.name),
                el("td", {}, describe(c)), el("td", { class: "num" }, c.fade_s ? fmt(c.fade_s, 1) : "cut"),
                el("td", { class: "num" }, c.follow_s === null || c.follow_s === undefined ? "GO" : fmt(c.follow_s, 1)),
                el("td", {}, c.slots && c.slots.length ? c.slots.join(", ") : "all"), buttons);
      tr.addEventListener("click", () => jump(c.id));
      tbody.appendChild(tr);
    });
    $("cues-empty").hidden = cues.length > 0;
  }

  function renderLine(st, cues) {
    $("cue-go").disabled = !cues.length;
    $("cue-back").disabled = !cues.length || st.current === null || st.current === undefined;
    const parts = [];
    if (st.current !== null && st.current !== undefined && cues[st.current]) {
      const c = cues[st.current];
      parts.push(`now ${c.id} ${c.name}${st.fired_at ? ` (fired ${ago(st.fired_at)}${st.fading ? ", fading" : ""})` : ""}`);
    } else {
      parts.push("no cue fired yet");
    }
    if (st.next !== null && st.next !== undefined && cues[st.next]) {
      const c = cues[st.next];
      const follow = st.follow_at ? `, follows in ${Math.max(0, Math.round(st.follow_at - Date.now() / 1000))} s` : "";
      parts.push(`next ${c.id} ${c.name}${follow}`);
    } else if (cues.length) {
      parts.push("the last cue is on");
    }
    $("cue-now").textContent = parts.join(" · ");
  }

  function renderTargets() {
    const list = $("cue-targets");
    clear(list);
    const kind = $("cue-kind").value;
    const names = kind === "pattern" ? PATTERNS : assets;
    for (const n of names) list.appendChild(el("option", { value: n }));
    $("cue-target").disabled = kind === "blackout";
  }

  async function load() {
    try { render(await api("/api/cues")); } catch (e) { $("cue-error").textContent = e.message; }
  }

  // ------------------------------------------------------------------ firing
  const fire = (path, body) => act($("cue-go"), $("cue-error"), async () => {
    const r = body ? await postJSON(path, body) : await api(path, { method: "POST" });
    await load();
    return r;
  });

  function go() { return fire("/api/cues/go"); }
  function back() { return fire("/api/cues/back"); }
  function jump(id) { return fire("/api/cues/jump", { id }); }

  // ------------------------------------------------------------------ editing (the whole list is sent)
  async function store(cues, errorEl) {
    await act($("cue-save"), errorEl || $("cue-form-error"), async () => {
      await postJSON("/api/cues", { cues });
      await load();
    });
  }

  function copy() {
    return cuesOf(state).map((c) => Object.assign({}, c, { slots: (c.slots || []).slice() }));
  }

  function move(k, step) {
    const cues = copy(), j = k + step;
    if (j < 0 || j >= cues.length) return;
    [cues[k], cues[j]] = [cues[j], cues[k]];
    store(cues, $("cue-error"));
  }

  function remove(k) {
    const cues = copy();
    cues.splice(k, 1);
    store(cues, $("cue-error"));
  }

  function edit(k) {
    const c = cuesOf(state)[k];
    if (!c) return;
    $("cue-edit-index").value = String(k);
    $("cue-name").value = c.name;
    $("cue-kind").value = c.kind;
    $("cue-target").value = c.target || "";
    $("cue-fade").value = String(c.fade_s || 0);
    $("cue-follow").value = c.follow_s === null || c.follow_s === undefined ? "" : String(c.follow_s);
    $("cue-slots").value = (c.slots || []).join(", ");
    $("cue-save").textContent = `Save cue ${c.id}`;
    $("cue-cancel-edit").hidden = false;
    renderTargets();
    $("cue-name").focus();
  }

  function endEdit() {
    $("cue-form").reset();
    $("cue-edit-index").value = "";
    $("cue-save").textContent = "Add cue";
    $("cue-cancel-edit").hidden = true;
    renderTargets();
  }

  function newId(cues) {
    let n = cues.length + 1;
    const taken = new Set(cues.map((c) => String(c.id)));
    while (taken.has(String(n))) n += 1;
    return String(n);
  }

  function fromForm(cues) {
    const kind = $("cue-kind").value;
    const fade = $("cue-fade").value.trim(), follow = $("cue-follow").value.trim();
    const cue = {
      name: $("cue-name").value.trim(), kind, target: kind === "blackout" ? "" : $("cue-target").value.trim(),
      fade_s: fade === "" ? 0 : Number(fade), follow_s: follow === "" ? null : Number(follow),
      slots: $("cue-slots").value.split(",").map((s) => s.trim()).filter((s) => s),
    };
    if (!cue.name) throw new Error("give the cue a name");
    if (kind !== "blackout" && !cue.target) throw new Error(`name the ${kind} this cue shows`);
    if (!(cue.fade_s >= 0)) throw new Error("the fade is a time in seconds, 0 or more");
    if (cue.follow_s !== null && !(cue.follow_s >= 0)) throw new Error("follow after is a time in seconds, or empty");
    const k = $("cue-edit-index").value;
    if (k !== "" && cues[Number(k)]) {
      cue.id = cues[Number(k)].id;
      cues[Number(k)] = cue;
    } else {
      cue.id = newId(cues);
      cues.push(cue);
    }
    return cues;
  }

  async function save(ev) {
    ev.preventDefault();
    $("cue-form-error").textContent = "";
    let cues;
    try { cues = fromForm(copy()); } catch (e) { $("cue-form-error").textContent = e.message; return; }
    await store(cues);
    if (!$("cue-form-error").textContent) endEdit();
  }

  // ------------------------------------------------------------------ wiring
  document.addEventListener("DOMContentLoaded", () => {
    $("cue-go").addEventListener("click", go);
    $("cue-back").addEventListener("click", back);
    $("cue-form").addEventListener("submit", save);
    $("cue-cancel-edit").addEventListener("click", endEdit);
    $("cue-kind").addEventListener("change", renderTargets);
    // the space bar fires GO while the focus is on the panel (not while typing in its form)
    $("cues-panel").addEventListener("keydown", (ev) => {
      if (ev.key !== " " || ev.repeat) return;
      const t = ev.target;
      if (t.closest("form") || ["INPUT", "SELECT", "TEXTAREA", "BUTTON"].includes(t.tagName)) return;
      ev.preventDefault();
      go();
    });
    // a click on the panel's free space gives it the focus, so the space bar fires GO
    $("cues-panel").addEventListener("mousedown", (ev) => {
      if (!ev.target.closest("button, input, select, textarea, form")) $("cues-panel").focus();
    });
    document.addEventListener("rig-snapshot", (ev) => {
      const s = ev.detail;
      const names = (s.assets || []).map((a) => a.name).filter((n) => n);
      if (names.join("\n") !== assets.join("\n")) { assets = names; renderTargets(); }
      if (s.cues) render(s.cues);
      else if (!state) load();
    });
    renderTargets();
  });
})();
