// Who is logged in: the login form's body (a name and a password, or the rig token with the name
// left empty), the name and role beside the Log out button, a viewer's page (every action button
// disabled: the coordinator refuses a viewer's actions with 403 anyway) and, for admins, the rig's
// users (added, given another role, removed here) and open sessions. Beside console.js (loaded
// first), whose helpers ($, el, clear, api, postJSON, showLogin) it uses.
"use strict";

// buttons that change nothing on the rig: a viewer keeps them (as any button marked data-viewer="keep")
const VIEWER_KEEPS = new Set(["logout", "camera-refresh", "calib-zoom-out", "calib-zoom-in", "calib-zoom-fit",
                              "select-all", "select-none"]);   // the layout's selection (layout.js) is the page's own
const VIEWER_TITLE = "a viewer sees everything and acts on nothing: ask an admin for the operator role";
let myRole = "";
let viewerWatch = null;

// The login request's body: {name, password}, or {token} when the name is left empty.
function loginBody() {
  const name = $("login-name").value.trim();
  const secret = $("token").value;
  return name ? { name: name, password: secret } : { token: secret };
}

function lockButton(b) {
  if (VIEWER_KEEPS.has(b.id) || b.dataset.viewer === "keep" || b.dataset.viewerLocked) return;
  b.dataset.viewerLocked = "1";
  b.disabled = true;
  b.title = VIEWER_TITLE;
}

// Disable every action of the page for a viewer (buttons added later too); undo it for other roles.
function lockForViewer() {
  const main = $("main-view");
  if (myRole === "viewer") {
    main.querySelectorAll("button").forEach(lockButton);
    if (!viewerWatch) {
      viewerWatch = new MutationObserver((records) => {
        for (const r of records) {
          if (r.type === "attributes" && r.target.dataset.viewerLocked && !r.target.disabled) r.target.disabled = true;
          for (const n of r.addedNodes || []) {
            if (n.nodeType !== 1) continue;
            if (n.tagName === "BUTTON") lockButton(n);
            n.querySelectorAll("button").forEach(lockButton);
          }
        }
      });
      viewerWatch.observe(main, { subtree: true, childList: true, attributes: true, attributeFilter: ["disabled"] });
    }
  } else {
    if (viewerWatch) { viewerWatch.disconnect(); viewerWatch = null; }
    main.querySelectorAll("button[data-viewer-locked]").forEach((b) => {
      delete b.dataset.viewerLocked;
      b.disabled = false;
      b.removeAttribute("title");
    });
  }
}

// Called by console.js once logged in (who: a user's name or "token"; role: viewer, operator or admin).
function applyRole(who, role) {
  myRole = role || "";
  document.body.dataset.role = myRole;
  $("who").textContent = myRole ? `${who} (${myRole})` : who;
  $("who").title = myRole === "viewer" ? VIEWER_TITLE : "";
  lockForViewer();
  showPeople();
}

// ------------------------------------------------------------------ admins: the rig's users
function peopleTable(id, heads) {
  const t = el("table", { id: id });
  const head = el("thead");
  const tr = el("tr");
  heads.forEach((h) => tr.append(el("th", {}, h)));
  head.append(tr);
  t.append(head, el("tbody"));
  return t;
}

const ROLES = ["viewer", "operator", "admin"];

function roleSelect(id, value) {
  const sel = el("select", id ? { id: id } : {});
  for (const r of ROLES) {
    const o = el("option", { value: r }, r);
    if (r === value) o.selected = true;
    sel.append(o);
  }
  return sel;
}

// Run a user change (POST), say any refusal in the panel, then show the list again.
async function peopleChange(path, doc) {
  $("people-error").textContent = "";
  try {
    await postJSON(path, doc);
  } catch (e) {
    $("people-error").textContent = e.message;
    if (e.status === 401) showLogin("Your session ended: log in again.");
    return false;
  }
  await showPeople();
  return true;
}

function peoplePanel() {
  let panel = $("people-panel");
  if (panel) return panel;
  panel = el("section", { class: "panel", id: "people-panel" });
  panel.append(el("h2", {}, "People"),
    el("p", { class: "muted" }, "Who may log in by name, and what they may do: a viewer sees, an operator acts, an " +
       "admin also manages the users. On the coordinator's machine: shadowless rig user add NAME --role operator. " +
       "Changes hold at the user's next request."),
    el("p", { id: "people-error", class: "error", role: "alert" }));
  const users = peopleTable("people-users", ["user", "role", "changed", ""]);
  const form = el("form", { id: "people-add", class: "controls", autocomplete: "off" });
  const name = el("input", { id: "people-name", type: "text", placeholder: "name", spellcheck: "false",
                             autocapitalize: "none", required: "" });
  const pw = el("input", { id: "people-password", type: "password", placeholder: "password (8 characters or more)",
                           autocomplete: "new-password", required: "" });
  form.append(el("label", { for: "people-name" }, "add"), name, roleSelect("people-role", "operator"), pw,
              el("button", { id: "people-add-button", type: "submit" }, "Add user"));
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    if (await peopleChange("/api/users", { name: name.value, role: $("people-role").value, password: pw.value })) {
      name.value = "";
      pw.value = "";
    }
  });
  const sessions = peopleTable("people-sessions", ["logged in", "role", "address", "idle (s)"]);
  panel.append(users, form, el("h3", {}, "Open sessions"), sessions);
  $("main-view").append(panel);
  return panel;
}

async function showPeople() {
  const existing = $("people-panel");
  if (myRole !== "admin") { if (existing) existing.hidden = true; return; }
  const panel = peoplePanel();
  panel.hidden = false;
  try {
    const r = await api("/api/users");
    const ub = panel.querySelector("#people-users tbody");
    clear(ub);
    for (const u of r.users) {
      const tr = el("tr", { "data-user": u.name });
      const sel = roleSelect("", u.role);
      sel.setAttribute("aria-label", `role of ${u.name}`);
      sel.addEventListener("change", () => peopleChange("/api/users/role", { name: u.name, role: sel.value }));
      const rm = el("button", { type: "button", class: "danger" }, "Remove");
      rm.addEventListener("click", () => {
        if (window.confirm(`Remove ${u.name}? Their open sessions end at their next request.`)) {
          peopleChange("/api/users/remove", { name: u.name });
        }
      });
      const roleCell = el("td");
      roleCell.append(sel);
      const rmCell = el("td");
      rmCell.append(rm);
      tr.append(el("td", {}, u.name), roleCell, el("td", {}, (u.changed || "").replace("T", " ")), rmCell);
      ub.append(tr);
    }
    if (!r.users.length) {
      const tr = el("tr");
      tr.append(el("td", { colspan: "4", class: "muted" }, "no users yet: everyone logs in with the rig token"));
      ub.append(tr);
    }
    const sb = panel.querySelector("#people-sessions tbody");
    clear(sb);
    for (const s of r.sessions) {
      const tr = el("tr");
      tr.append(el("td", {}, s.who), el("td", {}, s.role), el("td", {}, s.address), el("td", {}, s.idle_s));
      sb.append(tr);
    }
    $("people-error").textContent = r.file_error || "";
  } catch (e) {
    $("people-error").textContent = e.message;
  }
}
