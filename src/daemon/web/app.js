// handeye web page: polls the daemon's JSON API once a second and redraws what changed.
// No framework, no external file: the daemon serves this file from its binary.
"use strict";

const STAGES = ["preflight", "plan", "move", "settle", "capture", "register", "solve", "write_back", "return"];
const POLL_MS = 1000;
const TOKEN_KEY = "handeye-token";

const $ = (id) => document.getElementById(id);
let token = sessionStorage.getItem(TOKEN_KEY);
let pending = null;       // the action waiting for the token
let lastSeen = undefined; // last.run_id the page last drew
let latestCal = undefined;
let failures = 0;

function text(el, s) { el.textContent = s; }
function show(el, on) { el.hidden = !on; }
function fmt(v, digits) { return (typeof v === "number" && isFinite(v)) ? v.toFixed(digits) : "-"; }
// Times as everywhere else (CLI, API text, journal): 24-hour UTC.
function clock(d) {
  const pad = (n) => String(n).padStart(2, "0");
  return `${pad(d.getUTCHours())}:${pad(d.getUTCMinutes())}:${pad(d.getUTCSeconds())}`;
}
function when(unixS) {
  if (typeof unixS !== "number") return "-";
  const d = new Date(unixS * 1000);
  const pad = (n) => String(n).padStart(2, "0");
  return `${d.getUTCFullYear()}-${pad(d.getUTCMonth() + 1)}-${pad(d.getUTCDate())} ${clock(d)} UTC`;
}
function toneOf(outcome, drifted) {
  if (outcome === "accepted") return drifted ? "bad" : "good";
  if (outcome === "aborted") return "warn";
  if (outcome === "running" || outcome === "planned") return "muted";
  return "bad";
}
function chip(id, label, tone) {
  const el = $(id);
  text(el, label);
  el.dataset.tone = tone;
}
async function getJson(path) {
  const r = await fetch(path, { cache: "no-store" });
  if (!r.ok) {
    const body = await r.json().catch(() => ({}));
    const e = new Error(body.error || `${r.status} ${r.statusText}`);
    e.status = r.status;
    throw e;
  }
  return r.json();
}

// ---- actions: the token is asked once, then sent as the bearer token ----
function message(s, tone) {
  const el = $("message");
  text(el, s);
  el.dataset.tone = tone || "";
  show(el, true);
}

function ask(action) {
  pending = action;
  show($("message"), false);
  text($("message"), "");
  text($("token-action"), action);
  show($("token-box"), true);
  $("token").value = "";
  $("token").focus();
}

async function act(action) {
  if (token === null) { ask(action); return; }
  message(`Sending ${action}...`, "");
  const path = {
    calibrate: "/api/calibrate",
    check: "/api/check",
    cancel: "/api/cancel",
    remount: "/api/calibrate/accept-change",
  }[action];
  const headers = token ? { Authorization: `Bearer ${token}` } : {};
  // The history records an accepted remount as the page's.
  headers["X-Handeye-Client"] = "page";
  let r, body;
  try {
    r = await fetch(path, { method: "POST", headers, cache: "no-store" });
    body = await r.json().catch(() => ({}));
  } catch (e) {
    message(`Not sent: the daemon does not answer (${e.message}).`, "bad");
    return;
  }
  if (r.status === 401 || r.status === 403) {
    // A refused token is forgotten: the next press asks again.
    token = null;
    sessionStorage.removeItem(TOKEN_KEY);
    message(`Refused (${r.status}): ${body.error || r.statusText}. Nothing moved.`, "bad");
    return;
  }
  if (!r.ok) {
    message(`Refused (${r.status}): ${body.error || r.statusText}`, "bad");
    return;
  }
  if (token) sessionStorage.setItem(TOKEN_KEY, token);
  if (action === "cancel") {
    message(body.cancelled ? "Cancel sent: the arm is stopped where it is." : "Nothing was running.", "good");
  } else {
    const what = { check: "Check", calibrate: "Calibration", remount: "Calibration accepting the new mount" }[action];
    message(`${what} accepted: run ${body.run_id}.`, "good");
  }
  poll();
}

function wireActions() {
  $("btn-calibrate").addEventListener("click", () => act("calibrate"));
  $("btn-check").addEventListener("click", () => act("check"));
  $("btn-cancel").addEventListener("click", () => act("cancel"));
  // Asked in the page, not with window.confirm: a kiosk browser may suppress native dialogs.
  const remount = $("remount-dialog");
  $("btn-remount").addEventListener("click", () => {
    remount.returnValue = "";
    remount.showModal();
  });
  // Closed by either button, or by Escape (no value): only "accept" sends.
  remount.addEventListener("close", () => {
    if (remount.returnValue === "accept") act("remount");
    else message("Not sent. Nothing moved.", "");
  });
  $("token-box").addEventListener("submit", (ev) => {
    ev.preventDefault();
    token = $("token").value.trim();
    show($("token-box"), false);
    const action = pending;
    pending = null;
    if (action) act(action);
  });
  $("token-cancel").addEventListener("click", () => {
    show($("token-box"), false);
    pending = null;
    message("Not sent: no token given. Nothing moved.", "");
  });
  document.querySelectorAll("button[data-copy]").forEach((b) => {
    b.addEventListener("click", () => copy($(b.dataset.copy).textContent, b));
  });
  $("run-close").addEventListener("click", () => $("run-dialog").close());
}

async function copy(s, button) {
  try {
    await navigator.clipboard.writeText(s);
  } catch (_) {
    // Not a secure context (plain http from another host): select it for Ctrl+C.
    const ta = document.createElement("textarea");
    ta.value = s;
    document.body.appendChild(ta);
    ta.select();
    try { document.execCommand("copy"); } catch (_) { /* left selected */ }
    ta.remove();
  }
  const was = button.textContent;
  text(button, "Copied");
  setTimeout(() => text(button, was), 1200);
}

// ---- status ----
function drawStatus(st) {
  const running = st.state === "running";
  chip("chip-daemon", `daemon: ${st.state}`, running ? "busy" : st.state === "idle" ? "good" : "warn");
  chip("chip-robot", `robot: ${st.robot_connected ? "connected" : "not connected"}`, st.robot_connected ? "good" : "bad");
  chip("chip-camera", `camera: ${st.camera_connected ? "connected" : "not connected"}`, st.camera_connected ? "good" : "bad");
  show($("chip-alarm"), !!st.drift_alarm);
  $("btn-calibrate").disabled = running;
  $("btn-check").disabled = running;
  $("btn-remount").disabled = running;
  $("btn-cancel").disabled = !running;

  const now = $("now");
  const stages = $("stages");
  stages.replaceChildren();
  const cur = st.current;
  const at = cur && cur.stage ? STAGES.indexOf(cur.stage) : -1;
  STAGES.forEach((s, i) => {
    const li = document.createElement("li");
    text(li, s.replace("_", " "));
    if (cur && i < at) li.className = "done";
    if (cur && i === at) li.className = "active";
    stages.appendChild(li);
  });
  if (cur) {
    now.replaceChildren();
    const head = document.createElement("span");
    const step = at >= 0 ? ` - stage ${at + 1} of ${STAGES.length}: ${cur.stage.replace("_", " ")}` : "";
    text(head, `${cur.mode} ${cur.run_id} (${cur.trigger})${step}`);
    const detail = document.createElement("span");
    detail.className = "detail";
    text(detail, cur.detail || "");
    now.append(head, detail);
  } else {
    text(now, st.state === "idle" ? "Idle: ready for a run." : st.state);
  }

  const last = $("last");
  last.replaceChildren();
  if (st.last) {
    const l = st.last;
    const o = document.createElement("span");
    const drifted = l.drift ? l.drift.exceeded : false;
    o.className = `outcome tone-${toneOf(l.outcome, drifted)}`;
    text(o, l.verdict || (drifted ? "drifted" : l.outcome));
    const info = document.createElement("span");
    let d = "";
    if (l.drift) d = `, drift ${fmt(l.drift.translation_mm, 3)} mm / ${fmt(l.drift.rotation_deg, 4)}°`;
    text(info, ` ${l.mode} ${l.run_id}, ${when(l.finished_unix_s)}, ${fmt(l.duration_ms / 1000, 1)} s${d}`);
    last.append(o, info);
    appendLines(last, (l.reasons || []).slice(0, 3), "", "reason");
    appendLines(last, l.warnings, "warning: ", "reason");
  } else {
    text(last, "No run recorded yet.");
  }
}

function drawPicture(runId) {
  if (!runId) { show($("picture-link"), false); text($("picture-none"), "No run yet."); show($("picture-none"), true); return; }
  // Until the picture has loaded (or failed), say nothing rather than "No run yet." beside the run id.
  show($("picture-none"), false);
  const src = `/api/runs/${encodeURIComponent(runId)}/report.png`;
  const img = $("picture");
  img.onerror = () => { show($("picture-link"), false); text($("picture-none"), `Run ${runId} has no report picture.`); show($("picture-none"), true); };
  img.onload = () => { show($("picture-link"), true); show($("picture-none"), false); };
  img.src = src;
  img.dataset.run = runId;
  $("picture-link").href = src;
  text($("picture-run"), runId);
}

// ---- history ----
// The one word for a run, as the CLI, the API's status and the report picture say it: an
// accepted check that compared is "drifted" or "within limits", any other run its outcome.
function verdictOf(r) {
  if (r.mode === "check" && r.outcome === "accepted" && r.drifted != null) {
    return r.drifted ? "drifted" : "within limits";
  }
  return r.outcome;
}

function driftText(r) {
  if (r.drift_translation_mm != null) {
    return `drift ${fmt(r.drift_translation_mm, 3)} mm / ${fmt(r.drift_rotation_deg, 4)}°${r.drifted ? " (over the limit)" : ""}`;
  }
  if (r.reason) return r.reason;
  if (r.uncertainty_translation_mm != null) {
    return `±${fmt(r.uncertainty_translation_mm, 3)} mm / ±${fmt(r.uncertainty_rotation_deg, 4)}° (1σ)`;
  }
  return "";
}

async function drawHistory(fresh) {
  const data = await getJson("/api/runs?limit=50");
  const body = $("history").tBodies[0];
  body.replaceChildren();
  for (const r of data.runs) {
    const tr = document.createElement("tr");
    tr.dataset.run = r.run_id;
    if (r.run_id === fresh) tr.className = "fresh";
    const cells = [
      [when(r.started_unix_s), "when"],
      [r.mode, ""],
      [r.trigger, ""],
      [verdictOf(r), `outcome tone-${toneOf(r.outcome, r.drifted)}`],
      [driftText(r), "detail"],
      [r.duration_ms != null ? `${fmt(r.duration_ms / 1000, 1)} s` : "-", ""],
      [r.run_id, "run"],
    ];
    for (const [v, cls] of cells) {
      const td = document.createElement("td");
      if (cls) td.className = cls;
      text(td, v);
      tr.appendChild(td);
    }
    tr.addEventListener("click", () => openRun(r.run_id));
    body.appendChild(tr);
  }
  if (!data.runs.length) {
    const tr = document.createElement("tr");
    const td = document.createElement("td");
    td.colSpan = 7;
    td.className = "tone-muted";
    text(td, "No runs recorded yet.");
    tr.appendChild(td);
    body.appendChild(tr);
  }
}

// One line per item (a reason, a warning) under `parent`, as text, never markup.
function appendLines(parent, items, prefix, className) {
  for (const t of items || []) {
    const div = document.createElement("div");
    if (className) div.className = className;
    text(div, prefix + t);
    parent.appendChild(div);
  }
}

async function openRun(runId) {
  const dlg = $("run-dialog");
  text($("run-title"), `Run ${runId}`);
  text($("run-record"), "loading");
  $("run-reasons").replaceChildren();
  const src = `/api/runs/${encodeURIComponent(runId)}/report.png`;
  const img = $("run-picture");
  img.onerror = () => { show($("run-picture-link"), false); show($("run-picture-none"), true); };
  img.onload = () => { show($("run-picture-link"), true); show($("run-picture-none"), false); };
  img.src = src;
  $("run-picture-link").href = src;
  $("run-json").href = `/api/runs/${encodeURIComponent(runId)}`;
  if (!dlg.open) dlg.showModal();
  try {
    const rec = await getJson(`/api/runs/${encodeURIComponent(runId)}`);
    text($("run-title"), `${rec.mode || "run"} ${runId}: ${rec.outcome}`);
    appendLines($("run-reasons"), rec.reasons, "", "");
    appendLines($("run-reasons"), rec.warnings, "warning: ", "");
    text($("run-record"), JSON.stringify(rec, null, 2));
  } catch (e) {
    text($("run-record"), `cannot read the record: ${e.message}`);
  }
}

// ---- current calibration ----
async function drawCalibration() {
  let rec;
  try {
    rec = await getJson("/api/latest");
  } catch (e) {
    if (e.status === 404) { show($("cal-body"), false); show($("cal-none"), true); text($("cal-run"), ""); return; }
    throw e;
  }
  if (rec.run_id === latestCal) return;
  const ex = await getJson(`/api/runs/${encodeURIComponent(rec.run_id)}/exports`);
  latestCal = rec.run_id;
  const p = rec.result.ur_pose;
  text($("cal-x"), `${fmt(p[0] * 1000, 3)} mm`);
  text($("cal-y"), `${fmt(p[1] * 1000, 3)} mm`);
  text($("cal-z"), `${fmt(p[2] * 1000, 3)} mm`);
  text($("cal-rx"), `${fmt(p[3], 6)} rad`);
  text($("cal-ry"), `${fmt(p[4], 6)} rad`);
  text($("cal-rz"), `${fmt(p[5], 6)} rad`);
  const u = rec.result.uncertainty;
  const q = rec.result.report.quality;
  text($("cal-meta"), `uncertainty (1σ) ${fmt(u.translation_mm, 3)} mm / ${fmt(u.rotation_deg, 4)}°, coverage ${fmt(q.coverage * 100, 1)} %, rms ${fmt(q.rmse_mm, 3)} mm; written: ${(rec.written || []).map((w) => w.target).join(", ") || "nothing"}`);
  const eyeToHand = rec.result.mount === "eye_to_hand";
  text($("cal-unknown"), eyeToHand ? "base_from_camera" : "flange_from_camera (camera in tool0)");
  const m = ex.transform.matrix_row_major;
  text($("cal-matrix"), m.map((row) => row.map((v) => v.toFixed(6).padStart(10)).join(" ")).join("\n"));
  text($("exp-ur"), ex.transform.ur_pose);
  text($("exp-ros"), ex.static_transform_publisher.trim());
  text($("exp-urdf"), ex.urdf_joint.trim());
  text($("cal-run"), `run ${rec.run_id}`);
  show($("cal-none"), false);
  show($("cal-body"), true);
}

// ---- drift ----
async function drawDrift() {
  const img = $("drift");
  const w = Math.max(480, Math.min(1400, Math.round(img.clientWidth || 900)));
  img.src = `/api/drift.png?width=${w}&height=340&t=${Date.now()}`;
  const d = await getJson("/api/drift");
  const n = d.checks.length;
  const last = n ? d.checks[n - 1] : null;
  text($("drift-text"), n
    ? `${n} check(s); the last: ${fmt(last.translation_mm, 3)} mm / ${fmt(last.rotation_deg, 4)}° (limits ${d.max_translation_mm} mm / ${d.max_rotation_deg}°).`
    : `No checks yet (limits ${d.max_translation_mm} mm / ${d.max_rotation_deg}°).`);
}

// ---- the loop ----
async function poll() {
  let st;
  try {
    st = await getJson("/api/status");
    failures = 0;
    const t = new Date();
    chip("chip-link", `page: live ${clock(t)} UTC`, "good");
  } catch (e) {
    failures += 1;
    chip("chip-link", `page: no answer from the daemon (${failures})`, "bad");
    chip("chip-daemon", "daemon: unknown", "muted");
    chip("chip-robot", "robot: unknown", "muted");
    chip("chip-camera", "camera: unknown", "muted");
    return;
  }
  drawStatus(st);
  const lastId = st.last ? st.last.run_id : null;
  const runningId = st.current ? st.current.run_id : null;
  const key = `${lastId}|${runningId}`;
  if (key !== lastSeen) {
    lastSeen = key;
    try {
      await drawHistory(lastId);
      if (lastId) {
        drawPicture(lastId);
      } else {
        // Right after a restart the status has no last run: the history has.
        const first = $("history").tBodies[0].rows[0];
        drawPicture(first && first.dataset.run ? first.dataset.run : null);
      }
      await drawCalibration();
      await drawDrift();
    } catch (e) {
      message(`Cannot read the history: ${e.message}`, "bad");
    }
  }
}

wireActions();
poll();
setInterval(poll, POLL_MS);
