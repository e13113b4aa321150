// The console's blend panel: the rig's per-pixel blend (measured when, its headroom and what that
// costs), any failover as an alarm line at the top of the page whose "time since" counts up every
// second, and the lamps the photometric watchdog named with their estimated gains. Its own scope,
// beside console.js (loaded first), whose page helpers ($, el, clear, fmt) it uses; it follows the
// snapshot console.js receives (the "rig-snapshot" event). The before/after picture is drawn by
// pictures.js (from /api/pictures). Every piece of rig data goes on the page with textContent.
(() => {
  "use strict";

  const MAKE = "shadowless blend RIG";
  let blend = null;               // the snapshot's blend
  let ticker = null;

  function since(unix) {
    // how long ago a unix instant was, counted on this browser's clock, e.g. "12 s", "5 min", "2.0 h"
    const s = Math.max(0, Date.now() / 1000 - unix);
    if (s < 90) return `${Math.round(s)} s`;
    if (s < 5400) return `${Math.round(s / 60)} min`;
    if (s < 48 * 3600) return `${(s / 3600).toFixed(1)} h`;
    return `${Math.round(s / 86400)} d`;
  }

  function pct(x) {
    if (x === null || x === undefined) return "–";
    const p = 100 * x;
    return Math.abs(p) < 10 && Math.round(p * 10) % 10 !== 0 ? `${p.toFixed(1)} %` : `${Math.round(p)} %`;
  }

  // Who is out and since when (counted here), then the coordinator's verdict (how many projectors
  // cover the footprint; the snapshot's message) or one made from the flags; whether uniformity is
  // kept is said either way.
  function failoverText(b) {
    // who: the slots out of the blend, then the lamps the watchdog found dimmed (but still in it)
    const dimmed = (b.lamps || []).filter((l) => !b.lost.includes(l.slot)).map((l) => `lamp of ${l.slot} dimmed to ${pct(l.gain)}`);
    const lost = [b.lost.length ? `${b.lost.join(", ")} out of the blend` : "", ...dimmed].filter(Boolean).join(", ") ||
      "a projector out of the blend";
    const when = b.since ? ` ${since(b.since)} ago` : "";
    const whose = b.lost.length > 1 ? "their footprints" : "its footprint";
    const kept = b.covered ? "uniformity kept" : "uniformity NOT kept: part of the lost light has no other projector";
    let verdict = b.message || (b.covered ? `the others cover ${whose}` : `the others do not cover all of ${whose}`);
    if (!verdict.includes("uniformity")) verdict += `, ${kept}`;
    return `${lost}${when}: ${verdict}`;
  }

  function lampText(l) {
    const what = l.gain < 0.05 ? "dark" : l.gain < 1 ? "dimmed" : "brighter than measured";
    return `lamp ${l.slot} ${what}: estimated gain ${fmt(l.gain, 2)} (photometric watchdog)`;
  }

  // The parts that count time: called on every snapshot and once a second.
  function tick() {
    const b = blend;
    if (!b) return;
    const line = $("blend-line");
    if (b.state === "none") {
      line.textContent = `No blend yet: each projector shows at one gain and nothing covers a lost one. ` +
        `Run the blend job (Jobs: blend, above) or \`${MAKE}\` once the projectors are calibrated.` +
        (b.message && !b.message.includes("shadowless blend") ? ` (${b.message})` : "");
    } else {
      const measured = b.created_at ? `measured ${since(b.created_at)} ago` : "measured (time unknown)";
      line.textContent = `Blended: ${measured}, headroom ${pct(b.headroom)} ` +
        `(costs ${pct(b.brightness_cost)} of brightness)` +
        (b.state === "blended" && b.message ? `; ${b.message}` : "");
    }
    line.dataset.state = b.state;
    const failing = b.state === "failover" || b.lost.length > 0;
    const alarm = $("blend-alarm");
    alarm.hidden = !failing;
    alarm.className = failing ? `alarm ${b.covered ? "alarm-covered" : "alarm-uncovered"}` : "alarm";
    $("blend-alarm-text").textContent = failing ? failoverText(b) : "";
    const detail = $("blend-failover");
    detail.hidden = !failing;
    detail.textContent = failing ? failoverText(b) : "";
  }

  function render(b) {
    blend = b;
    const lamps = $("blend-lamps");
    clear(lamps);
    for (const l of (b && b.lamps) || []) lamps.appendChild(el("li", { "data-slot": l.slot }, lampText(l)));
    lamps.hidden = !lamps.children.length;
    tick();
  }

  document.addEventListener("rig-snapshot", (e) => { if (e.detail && e.detail.blend) render(e.detail.blend); });
  document.addEventListener("DOMContentLoaded", () => {
    if (!ticker) ticker = setInterval(tick, 1000);
  });
})();
