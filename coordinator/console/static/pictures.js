// The console's pictures: the alignment heat map, the compensation before/after picture (with
// their figures), the coverage of an object (shown once `shadowless coverage` ran), the blend's
// before/after uniformity picture (in the blend panel) and the camera's view. Its own scope, beside console.js (loaded first), whose
// page helpers ($, el, clear, fmt) it uses; every piece of rig data is put on the page with
// textContent or setAttribute, never as HTML.
// What exists comes from GET /api/pictures, polled while the page is open and asked again soon after
// the job line's state changes; a picture is loaded again when its file changed.
(() => {
  "use strict";

  const POLL_MS = 5000;           // /api/pictures, at most this far apart
  const CAMERA_MS = 4000;         // the camera view's automatic refresh
  let last = null;                // the last /api/pictures answer
  let pollTimer = null;
  let cameraTimer = null;
  let cameraLoading = false;
  let cameraOnScreen = false;

  function when(unix) {
    return unix ? new Date(unix * 1000).toLocaleString() : "";
  }

  function pageOpen() {
    return !$("main-view").hidden && document.visibilityState === "visible";
  }

  function jobRunning() {
    return !!(last && last.job && last.job.state === "running");
  }

  // ------------------------------------------------------------------ what exists
  async function refresh() {
    clearTimeout(pollTimer);
    pollTimer = null;
    if (!pageOpen()) { schedule(); return; }
    try {
      const resp = await fetch("/api/pictures", { credentials: "same-origin" });
      if (resp.ok) {
        last = await resp.json();
        render(last);
      }
    } catch (e) { /* the coordinator is away: try again later */ }
    schedule();
  }

  function schedule(ms) {
    clearTimeout(pollTimer);
    pollTimer = setTimeout(refresh, ms === undefined ? POLL_MS : ms);
  }

  function render(p) {
    renderAlignment(p.alignment);
    renderCompensation(p.compensation);
    renderCoverage(p.coverage);
    renderBlendPicture(p.blend);
    renderCamera(p.camera);
  }

  // Load a picture again only when its file changed (its URL carries the modification time).
  function showImage(img, url) {
    if (img.dataset.url !== url) { img.dataset.url = url; img.src = url; }
    img.hidden = false;
  }

  function renderAlignment(a) {
    const box = $("pic-alignment-maps"), table = $("pic-alignment-slots"), summary = $("pic-alignment-summary");
    if (!a) {
      clear(box);
      $("pic-alignment-when").textContent = "";
      summary.textContent = "No alignment check yet: run the alignment job after calibrating.";
      table.hidden = true;
      return;
    }
    $("pic-alignment-when").textContent = a.checked_at ? `checked ${when(a.checked_at)}` : "";
    const names = a.maps.map((m) => m.name).join(",");
    if (box.dataset.names !== names) { clear(box); box.dataset.names = names; }
    for (const m of a.maps) {
      let img = Array.from(box.querySelectorAll("img")).find((i) => i.dataset.name === m.name);
      if (!img) {
        img = el("img", { class: "pic-img", "data-name": m.name,
                          alt: `alignment heat map over the ${m.frame === "camera px" ? "camera image" : "table"}` });
        const link = el("a", { target: "_blank", rel: "noopener", title: "open at full size" });
        link.appendChild(img);
        box.appendChild(link);
      }
      img.parentNode.setAttribute("href", m.url);
      img.dataset.annotated = String(!!m.annotated);
      img.title = m.annotated ? `residual over the ${m.frame === "camera px" ? "camera image (camera px)" : "table (mm)"}`
        : "an older heat map without colour bar or axes: run the alignment job again";
      showImage(img, m.url);
    }
    const full = a.full_scale_px === null || a.full_scale_px === undefined ? 1 : a.full_scale_px;
    let text = a.worst_slot ? `Worst: ${a.worst_slot}, ${fmt(a.worst_rms_px, 3)} px rms. ` : "";
    text += `Red is ${full} projector px or more, grey has no dots.`;
    if (a.skipped && a.skipped.length) text += ` Not checked (no pose): ${a.skipped.join(", ")}.`;
    if (a.problem) text += ` ${a.problem}`;
    summary.textContent = text;
    const pixelMm = (a.maps[0] && a.maps[0].pixel_mm) || {};
    const tbody = table.tBodies[0];
    clear(tbody);
    for (const [slot, d] of Object.entries(a.slots || {})) {
      const mm = d.rms_px !== null && d.rms_px !== undefined && pixelMm[slot] ? d.rms_px * pixelMm[slot] : null;
      const tr = el("tr", { "data-slot": slot });
      tr.append(el("td", {}, slot), el("td", { class: "num" }, fmt(d.rms_px, 3)), el("td", { class: "num" }, fmt(d.p95_px, 3)),
                el("td", { class: "num" }, fmt(d.max_px, 3)), el("td", { class: "num" }, fmt(mm, 2)),
                el("td", { class: "num" }, `${d.dots === undefined ? "–" : d.dots}/${d.planned === undefined ? "–" : d.planned}`),
                el("td", { class: "reason" }, d.note || ""));
      tbody.appendChild(tr);
    }
    table.hidden = !tbody.rows.length;
  }

  const RESULTS = [["none", "before (without compensation)"], ["baseline", "per-projector baseline"],
                   ["ours", "after (compensated)"]];

  function renderCompensation(c) {
    const img = $("pic-compensation-img"), table = $("pic-compensation-scores"), summary = $("pic-compensation-summary");
    if (!c) {
      img.hidden = true;
      table.hidden = true;
      $("pic-compensation-when").textContent = "";
      summary.textContent = "No evaluated compensation yet: run the compensate job with evaluate.";
      return;
    }
    showImage(img, c.url);
    $("pic-compensation-link").setAttribute("href", c.url);
    $("pic-compensation-when").textContent = c.finished_at ? `evaluated ${when(c.finished_at)}` : "";
    const tbody = table.tBodies[0];
    clear(tbody);
    for (const [key, label] of RESULTS) {
      const s = c.scores && c.scores[key];
      if (!s) continue;
      const tr = el("tr", { "data-result": key });
      tr.append(el("td", {}, label), el("td", { class: "num" }, fmt(s.psnr, 2)), el("td", { class: "num" }, fmt(s.ssim, 4)));
      tbody.appendChild(tr);
    }
    table.hidden = !tbody.rows.length;
    const parts = [];
    if (c.image) parts.push(`Image ${c.image}`);
    const o = c.ordering || {};
    if (o.ours_minus_none_db !== undefined && o.ours_minus_none_db !== null) {
      parts.push(`after − before: ${o.ours_minus_none_db >= 0 ? "+" : ""}${fmt(o.ours_minus_none_db, 2)} dB PSNR`);
    }
    if (c.captures_averaged) parts.push(`${c.captures_averaged} captures averaged per result`);
    if (c.problem) parts.push(c.problem);
    summary.textContent = parts.join("; ");
  }

  // A rig that projects onto an object: how many projectors reach each point (a planar rig never
  // has one, so the figure stays hidden there).
  function renderCoverage(c) {
    const fig = $("pic-coverage"), table = $("pic-coverage-slots");
    fig.hidden = !c;
    if (!c) return;
    showImage($("pic-coverage-img"), c.url);
    $("pic-coverage-link").setAttribute("href", c.url);
    $("pic-coverage-when").textContent = c.computed_at ? `computed ${when(c.computed_at)}` : "";
    const parts = [];
    if (c.lit_pct !== null && c.lit_pct !== undefined) {
      parts.push(`${fmt(c.lit_pct, 1)} % of the surface reached by at least one of ${c.slots} projectors`);
    }
    if (c.count_mean !== null && c.count_mean !== undefined) {
      parts.push(`projectors per point: mean ${fmt(c.count_mean, 2)}, min ${c.count_min}, 5th percentile ${c.count_p5}`);
    }
    if (c.max_share_mean_pct !== null && c.max_share_mean_pct !== undefined) {
      parts.push(`one blocked projector takes at most ${fmt(c.max_share_mean_pct, 1)} % of the light (mean)`);
    }
    if (c.views && c.views.length) parts.push(`views: ${c.views.join(", ")}`);
    if (c.problem) parts.push(c.problem);
    $("pic-coverage-summary").textContent = parts.join("; ");
    const tbody = table.tBodies[0];
    clear(tbody);
    for (const [slot, d] of Object.entries(c.per_slot || {})) {
      const cm2 = (v) => (v === null || v === undefined ? null : v / 100);
      const tr = el("tr", { "data-slot": slot });
      tr.append(el("td", {}, slot), el("td", { class: "num" }, fmt(cm2(d.reach_mm2), 1)),
                el("td", { class: "num" }, fmt(d.reach_pct, 1)), el("td", { class: "num" }, fmt(d.mean_share_pct, 2)),
                el("td", { class: "num" }, fmt(cm2(d.sole_mm2), 1)));
      tbody.appendChild(tr);
    }
    table.hidden = !tbody.rows.length;
  }

  // The blend job's captures of flat white over their target, before and after blending, on one
  // colour scale, and the figures beside them; where there is no blend, how to make one.
  const BLEND_FIGURES = [
    ["uniformity_before", "non-uniformity before (p99 |I/target − 1|)", "pct"],
    ["uniformity_after", "non-uniformity after", "pct"],
    ["colour_after", "colour deviation after (worst channel)", "pct"],
    ["headroom", "headroom held for a lost projector", "pct"],
    ["brightness_cost", "brightness that headroom costs", "pct"],
    ["captures", "camera captures", "int"],
  ];

  function renderBlendPicture(b) {
    const img = $("pic-blend-img"), table = $("pic-blend-table"), summary = $("pic-blend-summary");
    const tbody = table.tBodies[0];
    clear(tbody);
    table.hidden = true;
    if (!b || !b.url) {
      img.hidden = true;
      $("pic-blend-when").textContent = "";
      summary.textContent = !b ? "No blend yet: run the blend job (Jobs: blend) or `shadowless blend RIG` " +
        "once the projectors are calibrated; its before/after picture appears here."
        : (b.problem || "The stored blend has no before/after pictures.");
      summary.dataset.state = !b ? "none" : "problem";
      if (!b) return;
    }
    if (b.url) {
      showImage(img, b.url);
      $("pic-blend-link").setAttribute("href", b.url);
      const [lo, hi] = b.range;
      summary.textContent = `Colour bar ${fmt(lo, 2)} (blue, darker than the target) to ${fmt(hi, 2)} ` +
        "(red, brighter); light grey is on target, dark grey no projector reaches." + (b.problem ? ` ${b.problem}` : "");
      summary.dataset.state = "shown";
    }
    $("pic-blend-when").textContent = b.created_at ? `measured ${when(b.created_at)}` : "";
    for (const [key, label, kind] of BLEND_FIGURES) {
      const v = b[key];
      if (v === null || v === undefined) continue;
      const tr = el("tr", { "data-figure": key });
      tr.append(el("td", {}, label), el("td", { class: "num" }, kind === "pct" ? `${fmt(100 * v, 2)} %` : String(v)));
      tbody.appendChild(tr);
    }
    if (b.slots && b.slots.length) {
      const tr = el("tr", { "data-figure": "slots" });
      tr.append(el("td", {}, "projectors blended"), el("td", { class: "num" }, String(b.slots.length)));
      tbody.appendChild(tr);
    }
    table.hidden = !tbody.rows.length;
  }

  // ------------------------------------------------------------------ the camera
  function renderCamera(cam) {
    const button = $("camera-refresh");
    if (!cam.configured) {
      $("camera-spec").textContent = "";
      $("camera-status").textContent = "No camera configured (rig.toml cameras).";
      $("camera-img").hidden = true;
      button.disabled = true;
      return;
    }
    button.disabled = false;
    $("camera-spec").textContent = cam.spec || "";
    const status = $("camera-status");
    if (jobRunning()) status.textContent = `The camera is in use by the running ${last.job.kind} job.`;
    else if (status.dataset.job) status.textContent = "";          // the job ended: its note goes
    status.dataset.job = jobRunning() ? "1" : "";
    if ($("camera-img").hidden && !$("camera-img").dataset.tried && !jobRunning()) loadCamera();
  }

  function loadCamera() {
    if (cameraLoading) return;
    cameraLoading = true;
    const img = $("camera-img");
    img.dataset.tried = "1";
    img.src = `/api/camera.png?t=${Date.now()}`;
  }

  async function cameraFailed() {
    // An <img> cannot read the answer: ask again for the message (the coordinator serves the same
    // refusal, or the same failed capture, within its rate limit).
    let message = "the camera view could not be loaded";
    try {
      const resp = await fetch($("camera-img").src, { credentials: "same-origin" });
      if (!resp.ok) {
        const body = await resp.json();
        if (body && body.error) message = body.error;
      } else {
        message = "";
      }
    } catch (e) { /* keep the general message */ }
    $("camera-error").textContent = message;
  }

  function autoCamera() {
    clearTimeout(cameraTimer);
    const cam = last && last.camera;
    if ($("camera-auto").checked && cam && cam.configured && cameraOnScreen && pageOpen() && !jobRunning()) loadCamera();
    cameraTimer = setTimeout(autoCamera, CAMERA_MS);
  }

  // ------------------------------------------------------------------ wiring
  document.addEventListener("DOMContentLoaded", () => {
    const img = $("camera-img");
    img.addEventListener("load", () => {
      cameraLoading = false;
      img.hidden = false;
      $("camera-error").textContent = "";
      $("camera-status").textContent = `view of ${new Date().toLocaleTimeString()}`;
      $("camera-status").dataset.job = "";
    });
    img.addEventListener("error", () => {
      cameraLoading = false;
      if (!img.getAttribute("src")) return;
      img.hidden = true;            // no broken-image icon: the reason is shown beside the button
      cameraFailed();
    });
    $("camera-refresh").addEventListener("click", () => { $("camera-error").textContent = ""; loadCamera(); });
    if ("IntersectionObserver" in window) {
      new IntersectionObserver((entries) => { cameraOnScreen = entries.some((e) => e.isIntersecting); })
        .observe($("pic-camera"));
    } else {
      cameraOnScreen = true;
    }
    // console.js sets the job line's class to job-<state>: a change (a job started or ended) asks again soon
    let jobClass = $("job-line").className;
    new MutationObserver(() => {
      const now = $("job-line").className;
      if (now !== jobClass) { jobClass = now; schedule(300); }
    }).observe($("job-line"), { attributes: true, attributeFilter: ["class"] });
    // the main view appears after the login: load at once
    new MutationObserver(() => { if (!$("main-view").hidden) schedule(0); })
      .observe($("main-view"), { attributes: true, attributeFilter: ["hidden"] });
    document.addEventListener("visibilitychange", () => { if (pageOpen()) schedule(0); });
    schedule(0);
    autoCamera();
  });
})();
