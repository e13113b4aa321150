// The health banner: one line when all is well (projectors live of those expected, slots without a
// pose), a coloured list of alarms when not (lost nodes and since when, frames missed lately, clocks
// not settled, assets not ready, recent refusals, a failover). Its data is the snapshot's `health`
// (coordinator/console/health.py); the times since are counted here, once a second, so the
// snapshot does not change every second. It also puts the command line's warning about slots
// without a pose beside Show and Play. An alarm makes the banner red and pulse (no sound: a
// show's operator may sit beside the audience). Rig data goes on the page as text only.
"use strict";

(function () {
  let last = null;

  function banner() {
    let b = document.getElementById("health");
    if (!b) {
      b = document.createElement("section");
      b.id = "health";
      b.className = "health health-ok";
      b.setAttribute("role", "status");
      b.setAttribute("aria-live", "polite");
      const main = document.getElementById("main-view");
      main.insertBefore(b, main.firstChild);
    }
    return b;
  }

  function since(unix) {
    if (unix === null || unix === undefined) return "";
    const s = Math.max(0, Date.now() / 1000 - unix);
    if (s < 90) return `${Math.round(s)} s ago`;
    if (s < 5400) return `${Math.round(s / 60)} min ago`;
    return `${(s / 3600).toFixed(1)} h ago`;
  }

  function plural(n, word) { return `${n} ${word}${n === 1 ? "" : "s"}`; }

  function countsLine(c) {
    const parts = [`${c.live} of ${plural(c.slots, "projector")} live`];
    if (c.lost) parts.push(`${c.lost} lost`);
    if (c.joined) parts.push(`${c.joined} joining`);
    if (c.expected) parts.push(`${c.expected} not connected`);
    parts.push(c.unposed ? `${c.unposed} without a pose` : "every slot has a pose");
    return parts.join(" · ");
  }

  function draw() {
    if (!last) return;
    const h = last;
    const b = banner();
    b.className = `health health-${h.level}`;
    b.setAttribute("data-level", h.level);
    while (b.firstChild) b.removeChild(b.firstChild);
    const head = document.createElement("div");
    head.className = "health-head";
    const badge = document.createElement("strong");
    badge.className = "health-badge";
    badge.textContent = { ok: "All well", warn: "Check", alarm: "Alarm" }[h.level] || h.level;
    const counts = document.createElement("span");
    counts.className = "health-counts";
    counts.textContent = countsLine(h.counts);
    head.append(badge, counts);
    b.appendChild(head);
    if (!h.alarms.length) return;
    const ul = document.createElement("ul");
    ul.className = "health-alarms";
    for (const a of h.alarms) {
      const li = document.createElement("li");
      li.className = `health-item level-${a.level} kind-${a.kind}`;
      li.setAttribute("data-kind", a.kind);
      li.setAttribute("data-slots", a.slots.join(" "));
      li.textContent = a.text + (a.since !== null ? ` (${since(a.since)})` : "");
      ul.appendChild(li);
    }
    b.appendChild(ul);
  }

  // Beside Show and Play: the warning the command line prints after `show` and `play` (the same
  // line, from the coordinator), while any slot has no pose.
  function drawUnposedWarning() {
    const panel = document.getElementById("content-panel");
    let p = document.getElementById("unposed-warning");
    if (!p) {
      p = document.createElement("p");
      p.id = "unposed-warning";
      p.className = "warn unposed-warning";
      p.setAttribute("role", "note");
      panel.insertBefore(p, panel.querySelector("h2").nextSibling);
    }
    const text = last && last.unposed_warning;
    p.textContent = text ? `warning: ${text}` : "";
    p.hidden = !text;
  }

  document.addEventListener("rig-snapshot", (e) => { last = e.detail.health || null; draw(); drawUnposedWarning(); });
  setInterval(() => { if (last && last.alarms.some((a) => a.since !== null)) draw(); }, 1000);
})();
