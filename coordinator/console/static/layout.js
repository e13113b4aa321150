// The layout: every posed slot's footprint on the table, readable when all of them overlap (the
// normal case: many projectors covering one table). A list of the slots sits beside the drawing;
// clicking a slot there or its footprint selects it: the selected footprints are drawn on top in
// their identify colour (the colour and number `Identify` puts on that projector), the others
// fade, and only the selected (up to six) and the hovered carry a label. The tools act on the selection:
// solo (only the selected projectors show the picture, the others black), and test patterns
// (none selected: every projector). Rig data goes on the page as text or attributes only.
"use strict";

(function () {
  const PATTERNS = [["grid", "grid"], ["crosshair", "crosshair"], ["bars", "colour bars"], ["white", "white"]];
  const MAX_LABELS = 6;      // the selected footprints labelled at once (the hovered one always is)
  const selected = new Set();
  let hovered = null;
  let last = null;

  function make(tag, attrs, text) { return el(tag, attrs, text); }

  function ensureUI() {
    if (document.getElementById("slot-list")) return;
    const panel = document.getElementById("layout-panel");
    const tools = make("div", { class: "controls slot-tools", id: "slot-tools" });
    const line = make("span", { id: "selection-line", class: "selection-line" }, "");
    const all = make("button", { type: "button", id: "select-all" }, "Select all");
    const none = make("button", { type: "button", id: "select-none" }, "Clear");
    const solo = make("button", { type: "button", id: "solo", title: "only the selected projectors show the picture; the others go black" }, "Solo");
    const unsolo = make("button", { type: "button", id: "solo-end", title: "every projector shows the picture again" }, "End solo");
    const pick = make("select", { id: "pattern-name", "aria-label": "test pattern" });
    for (const [v, label] of PATTERNS) pick.appendChild(make("option", { value: v }, label));
    const show = make("button", { type: "button", id: "pattern-show", title: "the pattern on the selected projectors (none selected: all); the others go black" }, "Show test pattern");
    const err = make("span", { id: "tools-error", class: "error", role: "alert" });
    tools.append(line, all, none, solo, unsolo, pick, show, err);
    panel.insertBefore(tools, panel.querySelector(".layout"));
    const side = panel.querySelector(".layout > div");
    const list = make("ul", { id: "slot-list", class: "slot-list", "aria-label": "slots: click to select" });
    side.insertBefore(list, side.firstChild);
    side.insertBefore(make("h3", {}, "Slots"), list);

    all.addEventListener("click", () => { if (last) for (const n of last.slots) selected.add(n.slot); redraw(); });
    none.addEventListener("click", () => { selected.clear(); redraw(); });
    solo.addEventListener("click", () => act(solo, err, () => postJSON("/api/solo", { slots: [...selected] })));
    unsolo.addEventListener("click", () => act(unsolo, err, () => postJSON("/api/solo", { slots: [] })));
    show.addEventListener("click", () => act(show, err, () => postJSON("/api/pattern",
      selected.size ? { name: pick.value, slots: [...selected] } : { name: pick.value })));
  }

  function toggle(slot) {
    if (selected.has(slot)) selected.delete(slot); else selected.add(slot);
    redraw();
  }

  function hover(slot) {
    if (hovered === slot) return;
    hovered = slot;
    redraw();
  }

  function mark(s, slot) {
    const m = s.health && s.health.marks && s.health.marks[slot];
    return m || { number: "", colour: "#888888" };
  }

  // a slot out of the blend (node lost, or a lamp the watchdog named) says so, with its lamp's gain
  function note(s, slot) {
    const lamp = ((s.blend && s.blend.lamps) || []).find((l) => l.slot === slot);
    const out = ((s.blend && s.blend.lost) || []).includes(slot);
    return (lamp ? `, lamp at ${fmt(lamp.gain, 2)}` : "") + (out ? ", out of the blend" : "");
  }

  function centre(fp) {
    return [fp.reduce((a, p) => a + p[0], 0) / fp.length, fp.reduce((a, p) => a + p[1], 0) / fp.length];
  }

  // Elements are kept per slot and updated in place: a click must not lose its target to a
  // snapshot (up to 4 a second) or a hover redrawing the layout between mouse down and up.
  const fps = new Map();      // slot -> {g, polygon, title}
  const items = new Map();    // slot -> {li, sw, num, name, st}
  const tiles = new Map();    // slot -> tile (slots without a pose)
  let frameKey = "";

  function drawSvg(s) {
    const svg = document.getElementById("layout");
    const [w, h] = s.rig.content_size;
    const m = 0.08 * Math.max(w, h);
    let x0 = -m, y0 = -m, x1 = w + m, y1 = h + m;
    for (const n of s.slots) {
      if (!n.footprint) continue;
      for (const [x, y] of n.footprint) {
        x0 = Math.min(x0, x - m / 2); y0 = Math.min(y0, y - m / 2);
        x1 = Math.max(x1, x + m / 2); y1 = Math.max(y1, y + m / 2);
      }
    }
    const fontSize = 0.045 * Math.max(w, h);
    const key = `${x0} ${y0} ${x1} ${y1} ${w} ${h}`;
    if (key !== frameKey || !svg.querySelector(".table-area")) {
      frameKey = key;
      svg.setAttribute("viewBox", `${x0} ${y0} ${x1 - x0} ${y1 - y0}`);
      clear(svg);
      fps.clear();
      svg.appendChild(svgEl("rect", { class: "table-area", x: -0.5, y: -0.5, width: w, height: h }));
      svg.appendChild(svgEl("text", { class: "fp-label", x: w / 2, y: h + m / 2, "font-size": fontSize * 0.8 },
                            `table: content ${w}×${h} px`));
    }
    for (const t of svg.querySelectorAll("text.fp-name")) t.remove();
    const out = new Set((s.blend && s.blend.lost) || []);
    const posed = s.slots.filter((n) => n.footprint);
    const keep = new Set(posed.map((n) => n.slot));
    for (const [slot, f] of fps) if (!keep.has(slot)) { f.g.remove(); fps.delete(slot); }
    // the selected and the hovered are drawn last, on top of the others
    const rank = (n) => (n.slot === hovered ? 2 : selected.has(n.slot) ? 1 : 0);
    posed.sort((a, b) => rank(a) - rank(b));
    const labels = [];
    for (const n of posed) {
      let f = fps.get(n.slot);
      if (!f) {
        const g = svgEl("g", { "data-slot": n.slot });
        const polygon = svgEl("polygon", {});
        const title = svgEl("title", {});
        g.append(polygon, title);
        g.addEventListener("click", () => toggle(n.slot));
        g.addEventListener("mouseenter", () => hover(n.slot));
        g.addEventListener("mouseleave", () => hover(null));
        f = { g, polygon, title };
        fps.set(n.slot, f);
      }
      const on = selected.has(n.slot), hot = n.slot === hovered;
      const cls = ["fp", `state-${n.state}`];
      if (out.has(n.slot)) cls.push("out-of-blend");
      if (on) cls.push("selected");
      if (hot) cls.push("hovered");
      if (selected.size && !on && !hot) cls.push("faded");
      f.g.setAttribute("class", cls.join(" "));
      f.polygon.setAttribute("class", `footprint state-${n.state}`);
      f.polygon.setAttribute("points", n.footprint.map(([x, y]) => `${x},${y}`).join(" "));
      // the colour Identify puts on that projector (a style: the state's colour comes from the style sheet)
      f.polygon.style.fill = on || hot ? mark(s, n.slot).colour : "";
      f.title.textContent = `${mark(s, n.slot).number} ${n.slot}: ${n.state}${note(s, n.slot)}`;
      if (hot || (on && selected.size <= MAX_LABELS)) {     // more labels at once would pile up again
        const [cx, cy] = centre(n.footprint);
        labels.push(svgEl("text", { class: "fp-label fp-name", x: cx, y: cy, "font-size": fontSize, "data-slot": n.slot },
                          `${mark(s, n.slot).number} ${n.slot}: ${n.state}`));
      }
    }
    // in drawing order, moving elements only when the order changed (a moved element can lose a click)
    const now = Array.from(svg.querySelectorAll("g[data-slot]")).map((g) => g.getAttribute("data-slot")).join("\n");
    if (now !== posed.map((n) => n.slot).join("\n")) for (const n of posed) svg.appendChild(fps.get(n.slot).g);
    for (const t of labels) svg.appendChild(t);     // above every footprint
  }

  function drawList(s) {
    const list = document.getElementById("slot-list");
    const out = new Set((s.blend && s.blend.lost) || []);
    const keep = new Set(s.slots.map((n) => n.slot));
    for (const [slot, it] of items) if (!keep.has(slot)) { it.li.remove(); items.delete(slot); }
    for (const n of s.slots) {
      let it = items.get(n.slot);
      if (!it) {
        const li = make("li", { "data-slot": n.slot, tabindex: "0", role: "button" });
        it = { li, sw: make("span", { class: "slot-swatch" }), num: make("span", { class: "slot-number" }),
               name: make("span", { class: "slot-name" }, n.slot), st: make("span", {}) };
        li.append(it.sw, it.num, it.name, it.st);
        li.addEventListener("click", () => toggle(n.slot));
        li.addEventListener("keydown", (ev) => { if (ev.key === " " || ev.key === "Enter") { ev.preventDefault(); toggle(n.slot); } });
        li.addEventListener("mouseenter", () => hover(n.slot));
        li.addEventListener("mouseleave", () => hover(null));
        items.set(n.slot, it);
      }
      const mk = mark(s, n.slot);
      it.li.setAttribute("class", `slot-item state-${n.state}${selected.has(n.slot) ? " selected" : ""}`);
      it.li.setAttribute("aria-pressed", String(selected.has(n.slot)));
      it.sw.style.backgroundColor = mk.colour;
      it.num.textContent = mk.number;
      it.st.setAttribute("class", `slot-state state-${n.state}`);
      it.st.textContent = n.state + (n.footprint ? "" : ", no pose") + note(s, n.slot);
      if (it.li.parentNode !== list) list.appendChild(it.li);
    }
  }

  function drawUnposed(s) {
    const unposed = document.getElementById("unposed");
    const out = new Set((s.blend && s.blend.lost) || []);
    const want = s.slots.filter((n) => !n.footprint);
    const head = unposed.previousElementSibling;
    if (head && head.tagName === "H3") head.hidden = !want.length;    // "Without a pose", when there are any
    const keep = new Set(want.map((n) => n.slot));
    for (const [slot, t] of tiles) if (!keep.has(slot)) { t.remove(); tiles.delete(slot); }
    for (const n of want) {
      let tile = tiles.get(n.slot);
      if (!tile) {
        tile = make("div", { "data-slot": n.slot }, n.slot);
        tile.addEventListener("click", () => toggle(n.slot));
        tiles.set(n.slot, tile);
        unposed.appendChild(tile);
      }
      tile.setAttribute("class", `tile state-${n.state}${out.has(n.slot) ? " out-of-blend" : ""}${selected.has(n.slot) ? " selected" : ""}`);
      tile.setAttribute("title", `${n.state}${note(s, n.slot)}`);
    }
  }

  function drawTools(s) {
    for (const slot of [...selected]) if (!s.slots.some((n) => n.slot === slot)) selected.delete(slot);
    const names = [...selected];
    const line = document.getElementById("selection-line");
    line.textContent = names.length ? `selected: ${names.length > 6 ? names.slice(0, 6).join(", ") + ` and ${names.length - 6} more` : names.join(", ")}`
      : "nothing selected (test patterns go to every projector)";
    document.getElementById("solo").disabled = !names.length;
  }

  function redraw() {
    if (!last) return;
    ensureUI();
    drawSvg(last);
    drawList(last);
    drawUnposed(last);
    drawTools(last);
  }

  document.addEventListener("rig-snapshot", (e) => { last = e.detail; redraw(); });
  // for scripts and tests: the current selection, and a way to set it
  window.slotSelection = { get: () => [...selected], set: (slots) => { selected.clear(); for (const s of slots) selected.add(s); redraw(); } };
})();
