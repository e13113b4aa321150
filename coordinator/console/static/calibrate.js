// Calibration from the page: the operator clicks known table points on the camera view (zoomed
// with the wheel or the buttons), types where each lies on the table in mm, drags a mark to move
// it, deletes one from its row; or chooses the ChArUco board lying on the table. "Calibrate" starts
// the calibrate job with the points ([x_mm, y_mm, u_px, v_px] each) or the board.
// Its own scope, beside console.js (loaded first), whose helpers ($, el, clear, svgEl, postJSON, act)
// it uses; every value is put on the page with textContent or setAttribute, never as HTML.
//
// Camera pixels: (0, 0) is the centre of the capture's top-left pixel, as the calibrate job reads
// table points. The view may be scaled down from the capture (GET /api/pictures says the capture's
// size), so a click at a fraction f of the picture's width is at f × capture width − 0.5.
(() => {
  "use strict";

  const ZOOM_STEP = 1.5;
  const ZOOM_MAX = 16;
  const MIN_POINTS = 4;
  const MARK_PX = 7;              // a mark's radius on screen, whatever the zoom
  const points = [];              // {u, v, x, y}: camera px, table mm (null until typed)
  let capture = null;             // [width, height] of the camera's captures
  let zoom = 1;                   // 1: the picture fits its frame
  let selected = -1;
  let drag = null;                // {index, pointerId} while a mark is dragged

  const img = () => $("camera-img");
  const round1 = (v) => Math.round(v * 10) / 10;

  function captureSize() {
    const i = img();
    return capture || (i.naturalWidth ? [i.naturalWidth, i.naturalHeight] : null);
  }

  // ------------------------------------------------------------------ view <-> camera pixels
  function toCamera(clientX, clientY) {
    const size = captureSize();
    const r = img().getBoundingClientRect();
    if (!size || !r.width || !r.height) return null;
    return [(clientX - r.left) / r.width * size[0] - 0.5, (clientY - r.top) / r.height * size[1] - 0.5];
  }

  function screenScale() {            // screen px per camera px
    const size = captureSize();
    const r = img().getBoundingClientRect();
    return size && r.width ? r.width / size[0] : 1;
  }

  // ------------------------------------------------------------------ zoom
  function applyZoom(anchor) {
    const vp = $("camera-viewport"), i = img();
    const before = i.getBoundingClientRect();
    vp.classList.toggle("fit", zoom === 1);
    if (zoom === 1) {
      i.style.width = "";
    } else {
      const base = Math.min(i.naturalWidth || vp.clientWidth, vp.clientWidth) || 1;
      i.style.width = `${Math.round(base * zoom)}px`;
    }
    $("calib-zoom").textContent = `${round1(zoom)}×`;
    if (anchor && before.width) {        // keep the point under the pointer where it was
      const fx = (anchor.clientX - before.left) / before.width, fy = (anchor.clientY - before.top) / before.height;
      const after = i.getBoundingClientRect(), vr = vp.getBoundingClientRect();
      vp.scrollLeft += after.left + fx * after.width - anchor.clientX;
      vp.scrollTop += after.top + fy * after.height - anchor.clientY;
      void vr;
    }
    drawMarks();
  }

  function setZoom(z, anchor) {
    zoom = Math.min(ZOOM_MAX, Math.max(1, z));
    applyZoom(anchor);
  }

  // ------------------------------------------------------------------ the marks and the table
  function drawMarks() {
    const svg = $("camera-marks"), size = captureSize();
    clear(svg);
    if (!size) return;
    svg.setAttribute("viewBox", `0 0 ${size[0]} ${size[1]}`);
    svg.setAttribute("preserveAspectRatio", "none");
    const r = MARK_PX / screenScale();
    points.forEach((p, k) => {
      const c = svgEl("circle", { class: `mark${k === selected ? " selected" : ""}`, cx: p.u + 0.5, cy: p.v + 0.5, r,
                                  "data-index": k });
      c.addEventListener("pointerdown", (ev) => startDrag(ev, k));
      svg.appendChild(c);
      svg.appendChild(svgEl("text", { x: p.u + 0.5 + 1.3 * r, y: p.v + 0.5 - 1.3 * r, "font-size": 2.2 * r }, k + 1));
    });
  }

  function renderTable() {
    const tbody = $("calib-points").tBodies[0];
    clear(tbody);
    points.forEach((p, k) => {
      const tr = el("tr", { "data-index": k, "data-u": p.u, "data-v": p.v, class: k === selected ? "selected" : "" });
      const mm = (key, label) => {
        const input = el("input", { type: "number", step: "any", "aria-label": `table ${key} of point ${k + 1} (mm)`,
                                    class: `calib-mm-${key}` });
        if (p[key] !== null) input.value = String(p[key]);
        input.addEventListener("input", () => { p[key] = input.value === "" ? null : Number(input.value); });
        input.addEventListener("focus", () => { selected = k; drawMarks(); });
        const td = el("td");
        td.appendChild(input);
        void label;
        return td;
      };
      const del = el("button", { type: "button", class: "calib-delete", title: `delete point ${k + 1}` }, "Delete");
      del.addEventListener("click", () => { points.splice(k, 1); selected = -1; renderAll(); });
      const delTd = el("td");
      delTd.appendChild(del);
      tr.append(el("td", {}, k + 1), el("td", { class: "num calib-u" }, p.u.toFixed(1)),
                el("td", { class: "num calib-v" }, p.v.toFixed(1)), mm("x"), mm("y"), delTd);
      tbody.appendChild(tr);
    });
  }

  function renderAll() {
    renderTable();
    drawMarks();
  }

  function updateRow(k) {            // while dragging: only the camera px of the row change
    const tr = $("calib-points").tBodies[0].rows[k];
    if (!tr) return;
    tr.setAttribute("data-u", points[k].u);
    tr.setAttribute("data-v", points[k].v);
    tr.querySelector(".calib-u").textContent = points[k].u.toFixed(1);
    tr.querySelector(".calib-v").textContent = points[k].v.toFixed(1);
  }

  // ------------------------------------------------------------------ pointer
  function startDrag(ev, k) {
    ev.preventDefault();
    ev.stopPropagation();
    selected = k;
    drag = { index: k, pointerId: ev.pointerId };
    $("camera-marks").setPointerCapture(ev.pointerId);
    drawMarks();
  }

  function moveDrag(ev) {
    if (!drag || ev.pointerId !== drag.pointerId) return;
    const at = toCamera(ev.clientX, ev.clientY);
    if (!at) return;
    const p = points[drag.index];
    [p.u, p.v] = [round1(at[0]), round1(at[1])];
    updateRow(drag.index);
    drawMarks();
  }

  function endDrag(ev) {
    if (!drag || ev.pointerId !== drag.pointerId) return;
    drag = null;
    renderAll();
  }

  function pick(ev) {
    if (!$("calib-pick").checked || drag || img().hidden) return;
    const at = toCamera(ev.clientX, ev.clientY);
    if (!at) return;
    points.push({ u: round1(at[0]), v: round1(at[1]), x: null, y: null });
    selected = points.length - 1;
    renderAll();
    const row = $("calib-points").tBodies[0].rows[selected];
    if (row) row.querySelector(".calib-mm-x").focus({ preventScroll: true });
  }

  // ------------------------------------------------------------------ the job
  function readFile(file) {
    return new Promise((resolve, reject) => {
      const r = new FileReader();
      r.onload = () => resolve(r.result);
      r.onerror = () => reject(r.error);
      r.readAsText(file);
    });
  }

  async function params() {
    const out = {};
    if ($("calib-table-only").checked) out.table_only = true;
    if ($("calib-way-points").checked) {
      if (points.length < MIN_POINTS) {
        throw new Error(`click at least ${MIN_POINTS} table points on the camera view (${points.length} so far)`);
      }
      const untyped = points.map((p, k) => (p.x === null || p.y === null || !isFinite(p.x) || !isFinite(p.y) ? k + 1 : 0))
        .filter((k) => k);
      if (untyped.length) throw new Error(`type the table position in mm of point ${untyped.join(", ")}`);
      out.table_points = points.map((p) => [p.x, p.y, p.u, p.v]);
    } else {
      const file = $("calib-board-file").files[0];
      if (file) {
        try { out.charuco = JSON.parse(await readFile(file)); } catch (e) {
          throw new Error(`${file.name} is not a board's JSON (shadowless rig board writes one): ${e.message}`);
        }
      }
    }
    return out;
  }

  function showWay() {
    const board = $("calib-way-board").checked;
    $("calib-points-tools").hidden = board;
    $("calib-board-tools").hidden = !board;
  }

  // ------------------------------------------------------------------ camera size
  async function learnCaptureSize() {
    try {
      const resp = await fetch("/api/pictures", { credentials: "same-origin" });
      if (!resp.ok) return;
      const doc = await resp.json();
      const size = doc && doc.camera && doc.camera.size;
      if (Array.isArray(size) && size.length === 2) capture = size;
    } catch (e) { /* the view's own size stands in */ }
    drawMarks();
  }

  // ------------------------------------------------------------------ wiring
  document.addEventListener("DOMContentLoaded", () => {
    const vp = $("camera-viewport"), marks = $("camera-marks");
    vp.classList.add("fit");
    img().addEventListener("load", () => { applyZoom(null); learnCaptureSize(); });
    img().addEventListener("click", pick);
    marks.addEventListener("click", (ev) => { if (ev.target === marks) pick(ev); });
    marks.addEventListener("pointermove", moveDrag);
    marks.addEventListener("pointerup", endDrag);
    marks.addEventListener("pointercancel", endDrag);
    vp.addEventListener("wheel", (ev) => {
      if (!$("calib-pick").checked) return;         // the page scrolls as usual unless picking points
      ev.preventDefault();
      setZoom(ev.deltaY < 0 ? zoom * ZOOM_STEP : zoom / ZOOM_STEP, ev);
    }, { passive: false });
    $("calib-pick").addEventListener("change", () => vp.classList.toggle("picking", $("calib-pick").checked));
    $("calib-zoom-in").addEventListener("click", () => setZoom(zoom * ZOOM_STEP));
    $("calib-zoom-out").addEventListener("click", () => setZoom(zoom / ZOOM_STEP));
    $("calib-zoom-fit").addEventListener("click", () => setZoom(1));
    $("calib-way-points").addEventListener("change", showWay);
    $("calib-way-board").addEventListener("change", showWay);
    $("calib-start").addEventListener("click", () => act($("calib-start"), $("calib-error"), async () => {
      await postJSON("/api/job", { kind: "calibrate", params: await params() });
    }));
    showWay();
    // without a camera (pictures.js disables its Refresh button) there is nothing to calibrate from
    const refresh = $("camera-refresh");
    const camera = () => { $("calib").hidden = refresh.disabled; };
    new MutationObserver(camera).observe(refresh, { attributes: true, attributeFilter: ["disabled"] });
    camera();
  });
})();
