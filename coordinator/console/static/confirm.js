// Stop and Blackout ask first, on the page: the first click opens a bar beside the buttons that
// says what will happen, with the action on a button of its own and "Keep showing" focused, so an
// Enter or a double click does not act; the bar closes by itself after a few seconds, and on
// Escape. (Not window.confirm: its OK has the focus, and an Enter goes through.) An undo instead
// was not chosen: a stopped timeline show cannot be put back where it was, and the dark seconds
// before an undo have been seen by the audience anyway.
"use strict";

(function () {
  const CLOSE_AFTER_MS = 8000;
  const ASK = {
    stop: { question: "Stop what plays and show the rig's content again (black if it has none)?",
            go: "Stop now", path: "/api/stop" },
    blackout: { question: "Black out every projector?", go: "Black out now", path: "/api/blackout" },
  };
  let timer = null;

  function bar() {
    let b = document.getElementById("confirm-bar");
    if (b) return b;
    b = el("div", { id: "confirm-bar", class: "confirm-bar", role: "alertdialog", "aria-live": "assertive", hidden: "" });
    const q = el("span", { id: "confirm-question", class: "confirm-question" });
    const go = el("button", { type: "button", id: "confirm-go", class: "danger" }, "");
    const keep = el("button", { type: "button", id: "confirm-cancel" }, "Keep showing");
    b.append(q, go, keep);
    const controls = document.getElementById("stop").parentNode;
    controls.parentNode.insertBefore(b, controls.nextSibling);
    keep.addEventListener("click", close);
    b.addEventListener("keydown", (ev) => { if (ev.key === "Escape") close(); });
    return b;
  }

  function close() {
    if (timer) { clearTimeout(timer); timer = null; }
    const b = document.getElementById("confirm-bar");
    if (b) { b.hidden = true; b.removeAttribute("data-action"); }
  }

  function ask(action) {
    const a = ASK[action];
    const b = bar();
    document.getElementById("confirm-question").textContent = a.question;
    const go = document.getElementById("confirm-go");
    go.textContent = a.go;
    go.onclick = () => {
      close();
      act(document.getElementById(action), document.getElementById("stop-error"), () => api(a.path, { method: "POST" }));
    };
    b.setAttribute("data-action", action);
    b.hidden = false;
    document.getElementById("confirm-cancel").focus();
    if (timer) clearTimeout(timer);
    timer = setTimeout(close, CLOSE_AFTER_MS);
  }

  document.addEventListener("DOMContentLoaded", () => {
    for (const action of Object.keys(ASK)) {
      document.getElementById(action).addEventListener("click", () => ask(action));
    }
  });
})();
