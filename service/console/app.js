/*
 * Regrasp operator console: plain JavaScript against the HTTP API of docs/contract.md section 5.
 * No build step: charts are inline SVG drawn here; the 3D view (view3d.js, an ES module on the
 * package's vendored three.js and urdf-loader) is driven through window.regrasp3d.
 *
 * One cursor links the views: a trajectory index chosen by hovering the margin chart, scrubbing
 * the timeline, hovering or clicking a segment row, or clicking the CoM trace in 3D; every view
 * follows it (setCursor). During execution a second cursor follows the index the controller
 * reports, and the measured joint states give an executed margin drawn against the planned one.
 *
 * Live progress: the job's Server-Sent Events stream (GET /v1/jobs/{id}/events) is read with
 * fetch() so that the bearer token goes in the Authorization header (EventSource cannot send
 * headers); if streaming is not possible the page polls GET /v1/jobs/{id} every 500 ms.
 *
 * Buttons follow the job's state and the token's roles (GET /v1/me): an action the token's
 * roles do not allow is not shown, and one a rule of the job forbids (two-person rule, "submitter
 * or admin") is shown disabled with the reason as its title. Against a service without /v1/me
 * the buttons follow the job's state only and a refused action shows the API's 403 detail.
 */
"use strict";

(function () {
  const TOKEN_KEY = "regrasp.token";
  const POLL_MS = 500;            // job polling period when SSE is unavailable
  const LIST_REFRESH_MS = 2000;   // job list refresh period
  const SSE_RETRY_MS = 1000;      // wait before re-opening an interrupted stream
  const TERMINAL = new Set(["succeeded", "failed", "canceled", "rejected", "aborted"]);
  const CANCELABLE = new Set(["queued", "planning", "planned", "approved"]);
  const EXECUTING = new Set(["dispatching", "executing"]);
  /* The role each action needs (docs/contract.md section 5); cancel needs the job's submitter or an admin. */
  const ROLE_OF = { approve: "approver", reject: "approver", dispatch: "operator", stop: "operator" };
  const HIDE = "hide";
  /* The site's CoM margin floor when the service does not say (schemas/policy.py's built-in default). */
  const DEFAULT_FLOOR_M = 0.03;
  /* One colour per hand configuration, the same as the CLI's plots (experiments/plots.py HANDS_COLOURS). */
  const HANDS_COLOURS = { "left-left": "#1f77b4", "right-right": "#ff7f0e", "left-right": "#2ca02c", "right-left": "#9467bd" };
  /* A gap between two measured states longer than this (s of plan time) breaks the executed trace. */
  const EXEC_GAP_S = 0.5;
  const SVG_NS = "http://www.w3.org/2000/svg";

  const state = {
    token: sessionStorage.getItem(TOKEN_KEY) || "",
    selected: null,      // id of the job shown
    job: null,           // last full job document shown
    stream: null,        // AbortController of the open SSE stream
    pollTimer: null,
    liveMode: "-",
    renderedResultFor: null,  // job id + plan hash whose charts are drawn
    // The token's identity from GET /v1/me: undefined while unknown or refused (role-bound actions
    // hidden), null when the service has no /v1/me (buttons by job state only), else {user, roles}.
    me: undefined,
    busy: false,         // an action's request is in flight: every action button is disabled
    identityPending: false,
    runningJob: null,    // a job the list shows dispatching or executing (the execution bar's, if none is shown)
    catalogue: null,     // GET /v1/catalogue: scenarios (with their own values), stances, hands, robots
    plan: null,          // the plan drawn (job result), with derived figures
    cursor: 0,           // trajectory index shown by every view
    exec: null,          // {jobId, index, points, trace: [[index, margin_m]], message} during/after execution
    risk: null,          // GET /v1/jobs/{id}/risk of the job shown
    riskFor: null,       // job id + state whose risk report is loaded
    urdfCache: {},       // robot name -> URDF text (served by the API)
    playTimer: null,
    health: null,        // GET /healthz (robot_id: what a recover job names)
    compare: null,       // {jobId, label, traj} a second plan drawn beside the one shown (a comparison, or the task's plan)
  };

  const $ = (id) => document.getElementById(id);

  // ------------------------------------------------------------------ HTTP
  class ApiError extends Error {
    constructor(status, detail, title) {
      super(detail || title || ("HTTP " + status));
      this.status = status;
      this.detail = detail;
      this.title = title;
    }
  }

  async function api(method, path, body) {
    const headers = { "Accept": "application/json, application/problem+json" };
    if (state.token) headers["Authorization"] = "Bearer " + state.token;
    if (body !== undefined) headers["Content-Type"] = "application/json";
    let response;
    try {
      response = await fetch(path, { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
    } catch (err) {
      throw new ApiError(0, "the service cannot be reached (" + err.message + ")");
    }
    const type = response.headers.get("Content-Type") || "";
    if (!response.ok) {
      let detail = "", title = response.statusText;
      if (type.includes("json")) {
        try {
          const problem = await response.json();
          detail = problem.detail || (Array.isArray(problem.errors) ? JSON.stringify(problem.errors) : "");
          title = problem.title || title;
        } catch (_) { /* keep the status text */ }
      } else {
        detail = (await response.text()).slice(0, 300);
      }
      throw new ApiError(response.status, detail, title);
    }
    if (response.status === 204) return null;
    return type.includes("json") ? response.json() : response.blob();
  }

  // ------------------------------------------------------------- utilities
  function el(tag, attrs, text) {
    const node = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === "class") node.className = v; else node.setAttribute(k, v);
    }
    if (text !== undefined && text !== null) node.textContent = String(text);
    return node;
  }

  function svg(tag, attrs, text) {
    const node = document.createElementNS(SVG_NS, tag);
    for (const [k, v] of Object.entries(attrs || {})) node.setAttribute(k, String(v));
    if (text !== undefined) node.textContent = String(text);
    return node;
  }

  const shortId = (id) => (id || "").slice(0, 8);
  const mm = (m) => (m === null || m === undefined || !isFinite(m)) ? "-" : (m * 1000).toFixed(1);
  const fmtTime = (iso) => { if (!iso) return "-"; const d = new Date(iso); return isNaN(d) ? iso : d.toLocaleTimeString([], { hour12: false }); };

  function showBanner(text, kind) {
    const b = $("banner");
    if (!text) { b.hidden = true; return; }
    b.textContent = text;
    b.className = "banner " + (kind || "info");
    b.hidden = false;
  }

  function showProblem(err) {
    const box = $("problem");
    if (!err) { box.hidden = true; box.textContent = ""; return; }
    const status = err.status ? (err.status + " " + (err.title || "")) : "error";
    box.textContent = status.trim() + ": " + (err.detail || err.message);
    box.hidden = false;
  }

  function stateBadge(node, jobState) {
    node.textContent = jobState;
    node.className = "state state-" + jobState;
    node.setAttribute("data-state", jobState);
  }

  // ----------------------------------------------------------------- token
  function setToken(token) {
    state.token = token.trim();
    if (state.token) sessionStorage.setItem(TOKEN_KEY, state.token); else sessionStorage.removeItem(TOKEN_KEY);
    $("token").value = "";
    $("token").placeholder = state.token ? "token set (" + state.token.slice(0, 6) + "...)" : "paste your token";
    showProblem(null);
    loadIdentity();
    refreshJobs();
    if (state.selected) selectJob(state.selected);
  }

  // -------------------------------------------------------------- identity
  async function loadIdentity() {
    const token = state.token;
    state.me = undefined;
    $("whoami").textContent = "";
    updateRoleViews();
    if (!token) return;
    let me;
    state.identityPending = true;
    try {
      me = await api("GET", "/v1/me");
    } catch (err) {
      // No /v1/me on this service: fall back to buttons by job state (a 403 then explains a refusal).
      if (state.token === token) { state.me = err.status === 404 ? null : undefined; updateRoleViews(); }
      return;
    } finally {
      if (state.token === token) state.identityPending = false;
    }
    if (state.token !== token) return;  // the token changed while asking
    state.me = { user: String(me.user), roles: Array.isArray(me.roles) ? me.roles.map(String) : [] };
    $("whoami").textContent = "signed in as " + state.me.user + " (" + (state.me.roles.join(", ") || "read only") + ")";
    $("whoami").dataset.roles = state.me.roles.join(",");
    updateRoleViews();
  }

  function hasRole(role) {
    return !!state.me && (state.me.roles.includes(role) || state.me.roles.includes("admin"));
  }

  function updateRoleViews() {
    // Submitting needs the planner role; the form stays hidden while the roles are unknown.
    $("submit-box").hidden = !(state.me === null || hasRole("planner"));
    if (state.job) updateButtons(state.job);
    if (state.job) updateExecBar(state.job);
    if (state.risk && state.job && state.risk.job_id === state.job.id) renderRisk(state.risk);  // its planner offer
  }

  /* Why the token may not do `action` on `job`: null if it may (or the page cannot tell),
     HIDE if its roles never allow it, else the reason (the button is shown disabled). */
  function refusal(action, job) {
    const me = state.me;
    if (me === null) return null;
    if (me === undefined) return HIDE;
    const role = ROLE_OF[action];
    if (role && !hasRole(role)) return HIDE;
    if ((action === "approve" || action === "reject") && job.submitter === me.user) {
      return "two-person rule: you submitted this job; another approver must review it";
    }
    if (action === "cancel" && job.submitter !== me.user && !hasRole("admin")) {
      return "only the submitter (" + job.submitter + ") or an admin can cancel this job";
    }
    return null;
  }

  // ---------------------------------------------------------------- health
  async function refreshHealth() {
    try {
      const h = await api("GET", "/healthz");
      state.health = h;
      const ctl = h.controller_alive === undefined ? "" : (h.controller_alive ? ", controller alive" : ", no controller");
      $("health").textContent = "service: " + (h.status || "ok") + ctl;
      $("health").className = "health " + ((h.status || "ok") === "ok" ? "ok" : "warn");
    } catch (err) {
      $("health").textContent = "service: unreachable";
      $("health").className = "health bad";
    }
  }

  // ------------------------------------------------------------------ jobs
  async function refreshJobs() {
    if (!state.token) {
      showBanner("Enter a bearer token to see the jobs (ask your administrator, or run `regrasp serve --dev`).", "info");
      $("jobs").querySelector("tbody").replaceChildren();
      return;
    }
    try {
      const list = await api("GET", "/v1/jobs?limit=100");
      showBanner(null);
      renderJobs(list.jobs || []);
    } catch (err) {
      if (err.status === 401) showBanner("The token was refused (401): " + (err.detail || "unknown token"), "error");
      else showBanner("Cannot list jobs: " + (err.detail || err.message), "error");
    }
  }

  function renderJobs(jobs) {
    const body = $("jobs").querySelector("tbody");
    const rows = jobs.map((job) => {
      const tr = el("tr", { "data-job-id": job.id, "data-state": job.state, "tabindex": "0" });
      if (job.id === state.selected) tr.classList.add("selected");
      tr.append(el("td", {}, shortId(job.id)));
      tr.append(el("td", {}, job.kind + (job.comparison ? " (comparison)" : "")));  // never for the robot
      const stateCell = el("td");
      const badge = el("span");
      stateBadge(badge, job.state);
      stateCell.append(badge);
      tr.append(stateCell);
      tr.append(el("td", {}, Math.round((job.progress || 0) * 100) + "%"));
      tr.append(el("td", {}, job.submitter));
      tr.append(el("td", {}, fmtTime(job.created_at)));
      tr.addEventListener("click", () => selectJob(job.id));
      tr.addEventListener("keydown", (e) => { if (e.key === "Enter") selectJob(job.id); });
      return tr;
    });
    body.replaceChildren(...rows);
    $("jobs-empty").hidden = jobs.length > 0;
    state.runningJob = jobs.find((j) => EXECUTING.has(j.state)) || null;
    updateExecBar(state.job);
  }

  // ---------------------------------------------------------------- detail
  async function selectJob(id) {
    if (state.selected !== id) {
      stopLive();
      state.renderedResultFor = null;
      showProblem(null);
    }
    state.selected = id;
    for (const tr of $("jobs").querySelectorAll("tbody tr")) tr.classList.toggle("selected", tr.dataset.jobId === id);
    try {
      const job = await api("GET", "/v1/jobs/" + encodeURIComponent(id));
      renderJob(job);
      if (!TERMINAL.has(job.state)) startLive(id); else stopLive();
    } catch (err) {
      showProblem(err);
    }
  }

  function renderJob(job) {
    state.job = job;
    $("detail-empty").hidden = true;
    $("detail-body").hidden = false;
    $("job-id").textContent = job.id;
    stateBadge($("job-state"), job.state);
    const executing = EXECUTING.has(job.state);
    // While the robot moves, the bar shows execution progress (the controller's index), not planning's.
    const fraction = executing ? execFraction(job) : (job.kind === "plan" && job.state === "succeeded") ? 1 : (job.progress || 0);
    $("job-progress-bar").style.width = Math.round(fraction * 100) + "%";
    $("job-progress-bar").dataset.kind = executing ? "execution" : "planning";
    $("job-progress-bar").parentElement.title = (executing ? "execution " : "planning ") + Math.round(fraction * 100) + " %";
    $("job-kind").textContent = job.kind;
    $("job-submitter").textContent = job.submitter;
    $("job-message").textContent = job.message || "-";
    $("job-sha").textContent = job.plan_sha256 || "-";
    $("job-audit").textContent = job.audit_head || "-";
    const a = job.approval;
    $("job-approval").textContent = a ? (a.approved_by + " at " + fmtTime(a.approved_at) + ", expires " + fmtTime(a.expires_at)) : "-";
    $("job-error").textContent = job.error ? (job.error.code + ": " + job.error.message) : "-";
    updateButtons(job);
    updateExecBar(job);
    renderComparisonNote(job);
    renderRecovery(job);
    loadRisk(job);
    // keep the list row in step
    const row = $("jobs").querySelector('tbody tr[data-job-id="' + job.id + '"]');
    if (row) {
      row.dataset.state = job.state;
      stateBadge(row.querySelector("span"), job.state);
      row.children[3].textContent = Math.round(fraction * 100) + "%";
    }
    const key = job.id + ":" + (job.plan_sha256 || "") + ":" + (job.result ? "r" : "-");
    if (key !== state.renderedResultFor) {
      state.renderedResultFor = key;
      renderResult(job);
    }
  }

  /* Buttons follow the job's state and what the token may do (see refusal()). */
  function updateButtons(job) {
    const s = job.state;
    // A comparison (planned below the site's floor) is never for the robot: nothing to approve or dispatch.
    const forRobot = (job.kind === "plan" || job.kind === "recover") && !job.comparison;
    const show = {
      approve: forRobot && s === "planned",
      reject: forRobot && s === "planned",
      dispatch: forRobot && s === "approved",
      cancel: CANCELABLE.has(s) && !(job.comparison && s !== "queued" && s !== "planning"),
    };
    const anyShown = [];
    for (const [action, fits] of Object.entries(show)) {
      const button = $("btn-" + action);
      const why = fits ? refusal(action, job) : HIDE;
      button.hidden = why === HIDE;
      // Stop is never held back by another request in flight.
      button.disabled = (action === "stop" ? false : state.busy) || (why !== null && why !== HIDE);
      if (why !== null && why !== HIDE) { button.title = why; button.dataset.refused = why; }
      else { button.removeAttribute("title"); delete button.dataset.refused; }
      if (!button.hidden) anyShown.push(action);
    }
    $("actions").dataset.shown = anyShown.join(",");
  }

  async function act(action) {
    const job = state.job;
    if (!job) return;
    showProblem(null);
    if ((action === "approve" || action === "dispatch") && !(await confirmAction(action, job))) return;
    let body;
    if (action === "approve") body = job.plan_sha256 ? { plan_sha256: job.plan_sha256 } : {};
    if (action === "stop" || action === "cancel") body = { reason: "operator console" };
    if (action === "reject") {
      const reason = await askRejectReason(job);
      if (reason === null) return;  // declined: nothing is sent
      body = { reason };
    }
    state.busy = true;
    for (const b of $("actions").querySelectorAll("button")) b.disabled = true;
    try {
      const updated = await api("POST", "/v1/jobs/" + encodeURIComponent(job.id) + "/" + action, body);
      if (updated && updated.id) renderJob(Object.assign({}, job, updated, { result: updated.result || job.result }));
      if (!TERMINAL.has((updated && updated.state) || job.state)) startLive(job.id);
      refreshJobs();
    } catch (err) {
      showProblem(err);
    } finally {
      state.busy = false;
      $("btn-audit").disabled = false;
      if (state.job) updateButtons(state.job);
    }
  }

  async function downloadAudit() {
    const job = state.job;
    if (!job) return;
    showProblem(null);
    try {
      const blob = await api("GET", "/v1/jobs/" + encodeURIComponent(job.id) + "/audit");
      const url = URL.createObjectURL(blob);
      const link = el("a", { href: url, download: job.id + ".mcap" });
      document.body.append(link);
      link.click();
      link.remove();
      setTimeout(() => URL.revokeObjectURL(url), 10000);
    } catch (err) {
      showProblem(err);
    }
  }

  // ------------------------------------------------------------------ live
  function setLiveMode(mode) {
    state.liveMode = mode;
    $("live-mode").textContent = mode;
    $("job-live").textContent = mode === "-" ? "" : "(live: " + mode + ")";
  }

  function stopLive() {
    if (state.stream) { state.stream.abort(); state.stream = null; }
    if (state.pollTimer) { clearInterval(state.pollTimer); state.pollTimer = null; }
    setLiveMode("-");
  }

  function startLive(id) {
    if (state.stream || state.pollTimer) return;
    if (window.ReadableStream && window.TextDecoder) streamEvents(id); else startPolling(id);
  }

  function startPolling(id) {
    if (state.pollTimer) return;
    setLiveMode("polling every " + POLL_MS + " ms");
    state.pollTimer = setInterval(async () => {
      if (state.selected !== id) { stopLive(); return; }
      try {
        const job = await api("GET", "/v1/jobs/" + encodeURIComponent(id));
        renderJob(job);
        if (TERMINAL.has(job.state)) { stopLive(); refreshJobs(); }
      } catch (err) { /* keep polling; the banner shows list errors */ }
    }, POLL_MS);
  }

  /* Server-Sent Events read with fetch (the Authorization header cannot go through EventSource). */
  async function streamEvents(id) {
    const controller = new AbortController();
    state.stream = controller;
    let lastEventId = null;
    setLiveMode("SSE");
    let refreshPending = false;
    const refresh = async () => {
      if (refreshPending) return;
      refreshPending = true;
      setTimeout(async () => {
        refreshPending = false;
        if (state.selected !== id) return;
        try { renderJob(await api("GET", "/v1/jobs/" + encodeURIComponent(id))); } catch (_) { /* next event retries */ }
      }, 100);
    };
    while (state.stream === controller) {
      try {
        const headers = { "Accept": "text/event-stream", "Authorization": "Bearer " + state.token };
        if (lastEventId) headers["Last-Event-ID"] = lastEventId;
        const response = await fetch("/v1/jobs/" + encodeURIComponent(id) + "/events", { headers, signal: controller.signal });
        if (!response.ok || !response.body || !(response.headers.get("Content-Type") || "").includes("text/event-stream")) {
          throw new Error("no event stream (HTTP " + response.status + ")");
        }
        const reader = response.body.getReader();
        const decoder = new TextDecoder();
        let buffer = "";
        let ended = false;
        while (!ended) {
          const { value, done } = await reader.read();
          if (done) break;
          buffer += decoder.decode(value, { stream: true }).replace(/\r\n?/g, "\n");
          let cut;
          while ((cut = buffer.indexOf("\n\n")) >= 0) {
            const block = buffer.slice(0, cut);
            buffer = buffer.slice(cut + 2);
            const event = parseSse(block);
            if (!event) continue;
            if (event.id) lastEventId = event.id;
            const terminal = applyEvent(event);
            // Progress and robot events are applied inline; the full job (with its possibly
            // large result) is fetched again only when the state or the approval changes.
            if (event.event === "state" || event.event === "approval") refresh();
            if (terminal) ended = true;
          }
        }
        if (ended || (state.job && TERMINAL.has(state.job.state))) {
          if (state.stream === controller) { state.stream = null; setLiveMode("-"); }
          refresh();
          refreshJobs();
          return;
        }
      } catch (err) {
        if (controller.signal.aborted) return;
        // Streaming unavailable (proxy, old server): fall back to polling.
        if (state.stream === controller) {
          state.stream = null;
          startPolling(id);
        }
        return;
      }
      await new Promise((r) => setTimeout(r, SSE_RETRY_MS));
    }
  }

  function parseSse(block) {
    const event = { event: "message", data: "", id: null };
    let hasData = false;
    for (const line of block.split("\n")) {
      if (!line || line.startsWith(":")) continue;
      const colon = line.indexOf(":");
      const field = colon < 0 ? line : line.slice(0, colon);
      let value = colon < 0 ? "" : line.slice(colon + 1);
      if (value.startsWith(" ")) value = value.slice(1);
      if (field === "event") event.event = value;
      else if (field === "data") { event.data += (hasData ? "\n" : "") + value; hasData = true; }
      else if (field === "id") event.id = value;
    }
    if (!hasData) return null;
    try { event.payload = JSON.parse(event.data); } catch (_) { event.payload = null; }
    return event;
  }

  /* Apply a state/progress event to the page at once; returns true at a terminal state. */
  function applyEvent(event) {
    const p = event.payload;
    if (!p || !state.job || (p.job_id && p.job_id !== state.job.id)) return false;
    const job = Object.assign({}, state.job);
    if (p.state) job.state = p.state;
    if (typeof p.progress === "number") job.progress = p.progress;
    if (event.event === "bridge") {
      const name = (p.data && p.data.event) || p.message || "event";
      const d = (p.data && p.data.payload) || {};
      const text = bridgeMessage(job, name, d);
      if (text) job.message = text;
    } else if (p.message) {
      job.message = p.message;
    }
    renderJob(job);
    return event.event === "state" && TERMINAL.has(p.state);
  }

  // --------------------------------------------------------------- results
  function renderResult(job) {
    const result = job.result;
    const isPlan = !!(result && Array.isArray(result.trajectory));
    const isSurvey = !!(result && Array.isArray(result.rows));
    $("plan-view").hidden = !isPlan;
    $("survey-view").hidden = !isSurvey;
    if (state.compare && state.compare.forJob !== job.id) state.compare = null;
    renderFailure(job);
    if (isPlan) renderPlan(result);
    if (isSurvey) renderSurvey(result);
  }

  /* A failed job says why first; a failed plan shows its scene as planned and no empty charts. */
  function renderFailure(job) {
    const box = $("failure-box");
    const plan = job.result;
    const failure = (plan && plan.failure) || (job.state === "failed" ? job.error : null);
    box.hidden = !failure;
    if (!failure) return;
    box.textContent = "Not planned: " + (failure.code ? failure.code + ": " : "") + (failure.message || "no message") +
      (plan && plan.trajectory && !plan.trajectory.length ? " The 3D view shows the scene as planned: the robot in its stance, the object where the task starts." : "");
    box.dataset.code = failure.code || "";
  }

  /* Inward offset of a convex polygon (the support polygon shrunk by the threshold). */
  function shrinkConvex(poly, d) {
    const n = poly.length;
    if (n < 3 || !(d > 0)) return poly.slice();
    let area = 0;
    for (let i = 0; i < n; i++) { const [x1, y1] = poly[i], [x2, y2] = poly[(i + 1) % n]; area += x1 * y2 - x2 * y1; }
    const pts = area >= 0 ? poly : poly.slice().reverse();
    const lines = [];
    for (let i = 0; i < n; i++) {
      const [x1, y1] = pts[i], [x2, y2] = pts[(i + 1) % n];
      const len = Math.hypot(x2 - x1, y2 - y1);
      if (len < 1e-12) continue;
      const nx = -(y2 - y1) / len, ny = (x2 - x1) / len;  // inward normal of a CCW polygon
      lines.push({ px: x1 + nx * d, py: y1 + ny * d, dx: (x2 - x1) / len, dy: (y2 - y1) / len });
    }
    const out = [];
    for (let i = 0; i < lines.length; i++) {
      const a = lines[(i + lines.length - 1) % lines.length], b = lines[i];
      const den = a.dx * b.dy - a.dy * b.dx;
      if (Math.abs(den) < 1e-12) continue;
      const t = ((b.px - a.px) * b.dy - (b.py - a.py) * b.dx) / den;
      out.push([a.px + a.dx * t, a.py + a.dy * t]);
    }
    // Nothing left if the offset turned the polygon inside out.
    let area2 = 0;
    for (let i = 0; i < out.length; i++) { const [x1, y1] = out[i], [x2, y2] = out[(i + 1) % out.length]; area2 += x1 * y2 - x2 * y1; }
    if (out.length < 3 || area2 <= 0) return [];
    for (const [x, y] of out) {
      for (const l of lines) if ((x - l.px) * -l.dy + (y - l.py) * l.dx < -1e-9) return [];
    }
    return out;
  }

  function chartFrame(container, width, height, label) {
    const root = svg("svg", { viewBox: "0 0 " + width + " " + height, width: "100%", role: "img", "aria-label": label });
    container.replaceChildren(root);
    return root;
  }

  function niceTicks(lo, hi, count) {
    const span = hi - lo || 1;
    const step0 = span / count;
    const mag = Math.pow(10, Math.floor(Math.log10(step0)));
    const step = [1, 2, 5, 10].map((f) => f * mag).find((s) => span / s <= count) || step0;
    const ticks = [];
    for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-12; v += step) ticks.push(Math.round(v / step) * step);
    return ticks;
  }

  /* hands: auto: the survey recommendation the plan followed (stats.survey_recommendation), with its 95 %
     interval, its seeds and the rows it cannot be told from; hidden for a plan that named its hands. */
  function renderPlanSurvey(plan) {
    const p = $("plan-survey");
    const rec = (plan.stats || {}).survey_recommendation;
    p.hidden = !(rec && typeof rec === "object" && rec.recommended);
    if (p.hidden) { p.textContent = ""; return; }
    const rows = rec.rows && typeof rec.rows === "object" ? rec.rows : {};
    const r3 = (v) => (typeof v === "number" ? v.toFixed(3) : "n/a");
    const one = (h, row) => h + " R = " + r3(row.ratio) +
      (Array.isArray(row.ratio_ci95) ? " [" + r3(row.ratio_ci95[0]) + ", " + r3(row.ratio_ci95[1]) + "]" : "") +
      (typeof row.seeds === "number" ? " over " + row.seeds + " seeds" : "");
    const ties = Array.isArray(rec.indistinguishable) ? rec.indistinguishable : [];
    p.dataset.tie = ties.length ? "true" : "false";
    p.textContent = "Hands chosen by the stability survey: " +
      one(rec.recommended, { ratio: rec.ratio, ratio_ci95: rec.ratio_ci95, seeds: rec.seeds }) +
      (ties.length ? "; a tie (overlapping 95 % intervals) with " + ties.map((h) => one(h, rows[h] || {})).join(", ") +
        ", tried in the tie order" : "; no other configuration's interval overlaps it") + ".";
  }

  function renderPlan(plan) {
    renderPlanSurvey(plan);
    const traj = plan.trajectory || [];
    const polygon = plan.support_polygon || [];
    const threshold = Number(plan.threshold_m || 0);
    const inner = shrinkConvex(polygon, threshold);
    state.plan = derivePlan(plan);
    if (!state.exec || state.exec.jobId !== (state.job && state.job.id)) state.exec = null;
    const moving = traj.length > 0;
    // No motion (a failed plan): no charts, timeline or segments to show empty; the scene as planned in 3D.
    for (const id of ["margin-chart", "com-chart", "segments"]) $(id).closest(id === "segments" ? "table" : "figure").hidden = !moving;
    $("timeline").closest(".timeline").hidden = !moving;
    if (!moving) {
      $("plan-summary").textContent = "status " + plan.status + ": no motion was planned" +
        (plan.failure ? " (" + plan.failure.code + ")" : "") + "; threshold " + mm(threshold) + " mm, hands " + (plan.hands || "-") + ".";
      show3d(plan);
      return;
    }
    drawComChart(polygon, inner, traj, threshold);
    drawMarginChart(traj, plan.segments || [], threshold, Number(plan.dt_s || 0));
    renderSegments(plan.segments || [], traj);
    const dur = traj.length ? traj[traj.length - 1].t : 0;
    const line = safetyLine(state.job, plan);
    const headroom = (typeof plan.min_margin_m === "number") ? plan.min_margin_m - line.value : null;
    const stats = plan.stats || {};
    const failures = stats.failures && typeof stats.failures === "object" ? Object.entries(stats.failures).filter(([, v]) => typeof v === "number" && v > 0) : [];
    $("plan-summary").textContent =
      "status " + plan.status + ", hands " + (plan.hands || "-") + ", " + traj.length + " points over " +
      Number(dur).toFixed(2) + " s, min margin " + mm(plan.min_margin_m) + " mm (planned with a threshold of " + mm(threshold) +
      " mm; headroom " + mm(headroom) + " mm against " + line.label + ")" +
      (failures.length ? "; rejected while planning: " + failures.map(([k, v]) => k + " " + v).join(", ") : "") +
      (plan.failure ? "; failure " + plan.failure.code + ": " + plan.failure.message : "") +
      // hands: auto: the quick survey that ranked the configurations, and how each one planned
      (stats.survey && typeof stats.survey === "object" && !stats.survey_recommendation ? ". Hands chosen by the stability survey (R): " +
        Object.entries(stats.survey).map(([h, r]) => h + " " + (typeof r === "number" ? r.toFixed(3) : "n/a")).join(", ") : "") +
      (stats.configurations && typeof stats.configurations === "object" && Object.keys(stats.configurations).length > 1
        ? "; configurations planned: " + Object.entries(stats.configurations).map(([h, c]) => h + " " + ((c && c.status) || "?")).join(", ") : "");
    const tl = $("timeline");
    tl.max = String(Math.max(traj.length - 1, 0));
    tl.value = "0";
    state.cursor = 0;
    show3d(plan);
    setCursor(state.plan.worst >= 0 ? state.plan.worst : 0, "plan");
  }

  /* Figures every view needs: time per index, segment per index, worst point, pick and place moments. */
  function derivePlan(plan) {
    const traj = plan.trajectory || [];
    const segOf = new Int32Array(traj.length).fill(-1);
    (plan.segments || []).forEach((seg, i) => { for (let k = Math.max(seg.first, 0); k <= Math.min(seg.last, traj.length - 1); k++) if (segOf[k] < 0) segOf[k] = i; });
    let worst = -1, best = Infinity;
    traj.forEach((p, i) => { if (typeof p.margin_m === "number" && p.margin_m < best) { best = p.margin_m; worst = i; } });
    const events = [];  // pick: an object taken off the table; place: put down; regrasp: handed over
    for (let i = 1; i < traj.length; i++) {
      const a = traj[i - 1].holding || "none", b = traj[i].holding || "none";
      if (a === b) continue;
      const kind = a === "none" ? "pick" : b === "none" ? "place" : "regrasp";
      events.push({ index: i, kind, from: a, to: b });
    }
    return { doc: plan, traj, segOf, worst, events, dt: Number(plan.dt_s || 0) };
  }

  async function robotUrdf(name) {
    if (!state.urdfCache[name]) {
      const headers = { "Authorization": "Bearer " + state.token, "Accept": "application/xml" };
      const r = await fetch("/v1/robots/" + encodeURIComponent(name) + "/urdf", { headers });
      if (!r.ok) throw new ApiError(r.status, "cannot load the URDF of robot " + name + " (HTTP " + r.status + ")");
      state.urdfCache[name] = await r.text();
    }
    return state.urdfCache[name];
  }

  async function fetchBinary(path) {
    const r = await fetch(path, { headers: { "Authorization": "Bearer " + state.token } });
    return r.ok ? r.arrayBuffer() : null;
  }

  async function fetchObjectMesh(name) {
    const r = await fetch("/v1/meshes/" + encodeURIComponent(name), { headers: { "Authorization": "Bearer " + state.token } });
    return r.ok ? r.text() : null;
  }

  async function show3d(plan) {
    const box = $("view3d");
    const v3 = window.regrasp3d;
    if (!v3) { box.dataset.status = "loading"; window.addEventListener("regrasp3d:ready", () => show3d(plan), { once: true }); return; }
    v3.fetchObjectMesh = fetchObjectMesh;
    v3.ensure(box);
    if (!v3.hasWebGL()) { box.dataset.status = "no-webgl"; return; }
    const name = plan.robot && plan.robot.name;
    box.dataset.status = "loading";
    try {
      const urdf = await robotUrdf(name);
      if (state.plan && state.plan.doc !== plan) return;  // another plan was selected meanwhile
      await v3.show(plan, urdf, fetchBinary);
      box.dataset.status = "drawn";
      box.dataset.robot = name;
      box.dataset.ghost = "";
      if ((plan.trajectory || []).length) v3.setIndex(state.cursor);
      drawCompare();
      box.dispatchEvent(new CustomEvent("regrasp3d:drawn"));
    } catch (err) {
      box.dataset.status = "error";
      v3.clear();
      box.title = "3D view: " + (err.detail || err.message);
    }
  }

  /* The one cursor: every view shows trajectory index i. */
  function setCursor(i, source) {
    const P = state.plan;
    if (!P || !P.traj.length) return;
    i = Math.max(0, Math.min(P.traj.length - 1, Math.round(i)));
    state.cursor = i;
    const p = P.traj[i];
    if (source !== "timeline") $("timeline").value = String(i);
    if (window.regrasp3d && $("view3d").dataset.status === "drawn" && !(state.exec && state.exec.live && source !== "user-3d")) window.regrasp3d.setIndex(i);
    moveChartCursor("margin", i);
    moveChartCursor("com", i);
    const seg = P.segOf[i];
    for (const tr of $("segments").querySelectorAll("tbody tr")) tr.classList.toggle("active", Number(tr.dataset.segment) === seg);
    const s = seg >= 0 ? P.doc.segments[seg] : null;
    $("cursor-readout").textContent = "t = " + Number(p.t).toFixed(2) + " s (point " + i + "), margin " + mm(p.margin_m) + " mm" +
      (s ? ", segment " + seg + " " + s.kind + " (" + s.hand + ")" : "") + ", holding " + (p.holding || "none") +
      (i === P.worst ? " - worst margin of the plan" : "");
    $("cursor-readout").dataset.index = String(i);
    $("cursor-readout").dataset.segment = String(seg);
  }

  function moveChartCursor(chart, i) {
    const c = state.charts && state.charts[chart];
    if (!c) return;
    c.cursor(i);
  }

  function playTimeline() {
    const P = state.plan;
    if (!P) return;
    if (state.playTimer) { clearInterval(state.playTimer); state.playTimer = null; $("timeline-play").textContent = "Play"; return; }
    $("timeline-play").textContent = "Pause";
    const stepMs = 40, stride = Math.max(1, Math.round(stepMs / 1000 / (P.dt || 0.005)));
    let i = state.cursor >= P.traj.length - 1 ? 0 : state.cursor;
    state.playTimer = setInterval(() => {
      i += stride;
      if (i >= P.traj.length - 1) { i = P.traj.length - 1; clearInterval(state.playTimer); state.playTimer = null; $("timeline-play").textContent = "Play"; }
      setCursor(i, "play");
    }, stepMs);
  }

  function drawComChart(polygon, inner, traj, threshold) {
    const W = 460, H = 360, pad = 44;
    const root = chartFrame($("com-chart"), W, H, "CoM trace over the support polygon");
    const pts = traj.filter((p) => Array.isArray(p.com)).map((p) => [p.com[0], p.com[1], p.margin_m]);
    const all = polygon.concat(pts.map((p) => [p[0], p[1]]));
    if (!all.length) { root.append(svg("text", { x: W / 2, y: H / 2, "text-anchor": "middle" }, "no geometry")); return; }
    let xmin = Math.min(...all.map((p) => p[0])), xmax = Math.max(...all.map((p) => p[0]));
    let ymin = Math.min(...all.map((p) => p[1])), ymax = Math.max(...all.map((p) => p[1]));
    const margin = 0.04;
    xmin -= margin; xmax += margin; ymin -= margin; ymax += margin;
    // equal scale on both axes so the polygon keeps its shape
    const scale = Math.min((W - 2 * pad) / (xmax - xmin), (H - 2 * pad) / (ymax - ymin));
    const cx = (xmin + xmax) / 2, cy = (ymin + ymax) / 2;
    const X = (x) => W / 2 + (x - cx) * scale;
    const Y = (y) => H / 2 - (y - cy) * scale;
    const path = (poly) => poly.map((p) => X(p[0]).toFixed(1) + "," + Y(p[1]).toFixed(1)).join(" ");

    const axes = svg("g", { class: "axes" });
    for (const t of niceTicks(xmin, xmax, 6)) {
      axes.append(svg("line", { x1: X(t), x2: X(t), y1: pad / 2, y2: H - pad, class: "gridline" }));
      axes.append(svg("text", { x: X(t), y: H - pad + 14, "text-anchor": "middle" }, (t * 1000).toFixed(0)));
    }
    for (const t of niceTicks(ymin, ymax, 6)) {
      axes.append(svg("line", { x1: pad, x2: W - pad / 2, y1: Y(t), y2: Y(t), class: "gridline" }));
      axes.append(svg("text", { x: pad - 4, y: Y(t) + 4, "text-anchor": "end" }, (t * 1000).toFixed(0)));
    }
    axes.append(svg("text", { x: W / 2, y: H - 6, "text-anchor": "middle" }, "x (mm, forward)"));
    axes.append(svg("text", { x: 12, y: H / 2, "text-anchor": "middle", transform: "rotate(-90 12 " + H / 2 + ")" }, "y (mm, left)"));
    root.append(axes);

    if (polygon.length >= 3) root.append(svg("polygon", { points: path(polygon), class: "support", "data-role": "support" }));
    if (inner.length >= 3) root.append(svg("polygon", { points: path(inner), class: "threshold", "data-role": "threshold" }));
    if (pts.length) {
      root.append(svg("polyline", { points: path(pts), class: "com-trace", "data-role": "com-trace" }));
      const bad = pts.filter((p) => typeof p[2] === "number" && p[2] < threshold - 1e-4);
      for (const p of bad) root.append(svg("circle", { cx: X(p[0]), cy: Y(p[1]), r: 2.5, class: "com-bad" }));
      const s = pts[0], e = pts[pts.length - 1];
      root.append(svg("circle", { cx: X(s[0]), cy: Y(s[1]), r: 5, class: "com-start" }));
      root.append(svg("rect", { x: X(e[0]) - 4, y: Y(e[1]) - 4, width: 8, height: 8, class: "com-end" }));
    }
    const zmp = traj.filter((p) => Array.isArray(p.zmp)).map((p) => [p.zmp[0], p.zmp[1]]);
    if (zmp.length) root.insertBefore(svg("polyline", { points: path(zmp), class: "zmp-trace", "data-role": "zmp-trace" }), root.querySelector('[data-role="com-trace"]'));
    const P = state.plan;
    if (P && P.worst >= 0 && Array.isArray(traj[P.worst].com)) {
      const w = traj[P.worst].com;
      root.append(svg("circle", { cx: X(w[0]), cy: Y(w[1]), r: 6, class: "worst-ring", "data-role": "worst" }));
    }
    const legend = svg("g", { class: "legend", transform: "translate(" + (pad + 6) + "," + 16 + ")" });
    const items = [["support", "support polygon"], ["threshold", "shrunk by " + mm(threshold) + " mm"], ["com-trace", "CoM"], ["zmp-trace", "ZMP"],
      null, ["cop-trace", "CoP (robot)"], ["com-start", "start"], ["compare-com", "other plan"]];  // null: a second row
    let lx = 0, ly = 0;
    items.forEach((item) => {
      if (item === null) { lx = 0; ly += 14; return; }
      const [cls, label] = item;
      legend.append(svg("line", { x1: lx, x2: lx + 18, y1: ly, y2: ly, class: cls + " legend-line" }));
      legend.append(svg("text", { x: lx + 22, y: ly + 4 }, label));
      lx += 34 + label.length * 5.6;
    });
    root.append(legend);
    // The robot's measured centre of pressure (the physics plant's state/balance, live), beside the planned ZMP.
    const copTrace = svg("polyline", { points: "", class: "cop-trace", "data-role": "cop-trace" });
    const copDot = svg("circle", { cx: -10, cy: -10, r: 4, class: "cop-dot", "data-role": "cop-dot", visibility: "hidden" });
    root.append(copTrace);
    const dot = svg("circle", { cx: -10, cy: -10, r: 5, class: "cursor-dot", "data-role": "cursor" });
    const zdot = svg("rect", { x: -10, y: -10, width: 7, height: 7, class: "zmp-dot" });
    const edot = svg("circle", { cx: -10, cy: -10, r: 6, class: "exec-dot", "data-role": "exec-dot", visibility: "hidden" });
    root.append(zdot, dot, edot, copDot);
    state.charts = state.charts || {};
    const copPoints = [];
    state.charts.com = {
      cop(x, y) {
        copPoints.push(X(x).toFixed(1) + "," + Y(y).toFixed(1));
        copTrace.setAttribute("points", copPoints.join(" "));
        copDot.setAttribute("cx", X(x)); copDot.setAttribute("cy", Y(y)); copDot.setAttribute("visibility", "visible");
        root.dataset.copSamples = String(copPoints.length);
      },
      cursor(i) {
        const p = traj[i];
        if (!p) return;
        if (Array.isArray(p.com)) { dot.setAttribute("cx", X(p.com[0])); dot.setAttribute("cy", Y(p.com[1])); }
        if (Array.isArray(p.zmp)) { zdot.setAttribute("x", X(p.zmp[0]) - 3.5); zdot.setAttribute("y", Y(p.zmp[1]) - 3.5); }
        root.dataset.cursor = String(i);
      },
      exec(i, measured) {
        const c = measured ? measured.com : (traj[i] && traj[i].com);
        if (!Array.isArray(c)) return;
        edot.setAttribute("cx", X(c[0])); edot.setAttribute("cy", Y(c[1])); edot.setAttribute("visibility", "visible");
      },
      compare(other, label) {
        const cpts = other.filter((p) => Array.isArray(p.com)).map((p) => [p.com[0], p.com[1]]);
        const line = svg("polyline", { points: path(cpts), class: "compare-com", "data-role": "compare-com" });
        const old = root.querySelector('[data-role="compare-com"]');
        if (old) old.remove();
        root.insertBefore(line, root.querySelector('[data-role="com-trace"]'));
        line.append(svg("title", {}, label));
        root.dataset.compare = "drawn";
      },
    };
  }

  function drawMarginChart(traj, segments, threshold, dt) {
    const W = 460, H = 360, padL = 52, padR = 12, padT = 26, padB = 40;
    const root = chartFrame($("margin-chart"), W, H, "Stability margin over time");
    state.charts = state.charts || {};
    state.charts.margin = null;
    const pts = traj.map((p, i) => [typeof p.t === "number" ? p.t : i * dt, p.margin_m]).filter((p) => typeof p[1] === "number");
    if (!pts.length) { root.append(svg("text", { x: W / 2, y: H / 2, "text-anchor": "middle" }, "no margins")); return; }
    const tmin = pts[0][0], tmax = Math.max(pts[pts.length - 1][0], tmin + 1e-6);
    let mmin = Math.min(0, threshold, ...pts.map((p) => p[1])), mmax = Math.max(threshold, ...pts.map((p) => p[1]));
    mmax += (mmax - mmin) * 0.12 || 0.01;
    const X = (t) => padL + (t - tmin) / (tmax - tmin) * (W - padL - padR);
    const Y = (m) => H - padB - (m - mmin) / (mmax - mmin) * (H - padT - padB);
    const tOf = (i) => (traj[i] && typeof traj[i].t === "number") ? traj[i].t : i * dt;
    const palette = { transit: "band-transit", transfer: "band-transfer", handover: "band-handover", approach: "band-approach", retreat: "band-retreat" };
    segments.forEach((seg, i) => {
      const a = traj[seg.first], b = traj[seg.last];
      if (!a || !b) return;
      const x1 = X(tOf(seg.first)), x2 = X(tOf(seg.last));
      root.append(svg("rect", { x: x1, y: padT, width: Math.max(1, x2 - x1), height: H - padT - padB,
        class: "band " + (palette[seg.kind] || "band-other") + (i % 2 ? " band-odd" : ""), "data-segment": i }));
      if (x2 - x1 > 34) root.append(svg("text", { x: (x1 + x2) / 2, y: padT - 6, "text-anchor": "middle", class: "band-label" }, seg.kind));
    });
    for (const t of niceTicks(tmin, tmax, 6)) {
      root.append(svg("line", { x1: X(t), x2: X(t), y1: padT, y2: H - padB, class: "gridline" }));
      root.append(svg("text", { x: X(t), y: H - padB + 14, "text-anchor": "middle" }, t.toFixed(t < 10 ? 1 : 0)));
    }
    for (const m of niceTicks(mmin, mmax, 6)) {
      root.append(svg("line", { x1: padL, x2: W - padR, y1: Y(m), y2: Y(m), class: "gridline" }));
      root.append(svg("text", { x: padL - 4, y: Y(m) + 4, "text-anchor": "end" }, (m * 1000).toFixed(0)));
    }
    root.append(svg("text", { x: (W + padL) / 2, y: H - 6, "text-anchor": "middle" }, "time (s)"));
    root.append(svg("text", { x: 12, y: H / 2, "text-anchor": "middle", transform: "rotate(-90 12 " + H / 2 + ")" }, "CoM margin (mm)"));
    root.append(svg("line", { x1: padL, x2: W - padR, y1: Y(threshold), y2: Y(threshold), class: "threshold-line", "data-role": "threshold-line" }));
    root.append(svg("text", { x: W - padR - 4, y: Y(threshold) - 5, "text-anchor": "end", class: "threshold-label" }, "threshold " + mm(threshold) + " mm"));
    root.append(svg("polyline", { points: pts.map((p) => X(p[0]).toFixed(1) + "," + Y(p[1]).toFixed(1)).join(" "), class: "margin-line", "data-role": "margin-line" }));
    // Pick, place and regrasp moments: the margin jumps there as the object's mass joins or leaves the CoM.
    const P = state.plan;
    for (const ev of (P ? P.events : [])) {
      const x = X(tOf(ev.index));
      root.append(svg("line", { x1: x, x2: x, y1: padT, y2: H - padB, class: "event-line event-" + ev.kind, "data-role": "event", "data-kind": ev.kind }));
      root.append(svg("text", { x: x + 3, y: padT + 12, class: "event-label" }, ev.kind));
    }
    if (P && P.worst >= 0) {
      const w = traj[P.worst];
      root.append(svg("circle", { cx: X(tOf(P.worst)), cy: Y(w.margin_m), r: 5, class: "worst-point", "data-role": "worst" }));
      root.append(svg("text", { x: X(tOf(P.worst)) + 7, y: Y(w.margin_m) + 14, class: "worst-label" }, "worst " + mm(w.margin_m) + " mm"));
    }
    const compareLine = svg("polyline", { points: "", class: "compare-line", "data-role": "compare-line" });
    root.append(compareLine);
    // The executed margin: one polyline per run of measured states (never a line across a gap without measurements).
    const execTrace = svg("g", { "data-role": "exec-trace" });
    root.append(execTrace);
    const execCursor = svg("line", { x1: -10, x2: -10, y1: padT, y2: H - padB, class: "exec-cursor", "data-role": "exec-cursor", visibility: "hidden" });
    const execLabel = svg("text", { x: -100, y: padT + 24, class: "exec-cursor-label", "data-role": "exec-cursor-label", visibility: "hidden" }, "");
    root.append(execCursor, execLabel);
    const cursor = svg("line", { x1: -10, x2: -10, y1: padT, y2: H - padB, class: "cursor", "data-role": "cursor" });
    const dot = svg("circle", { cx: -10, cy: -10, r: 4, class: "cursor-dot" });
    root.append(cursor, dot);
    // legend
    const legend = svg("g", { class: "legend", transform: "translate(" + (padL + 6) + "," + (H - padB - 10) + ")" });
    const legendItems = [["margin-line", "planned"], ["exec-line", "executed (measured)"], ["exec-cursor", "robot now"]];
    let lx = 0;
    legendItems.forEach(([cls, label]) => {
      legend.append(svg("line", { x1: lx, x2: lx + 16, y1: 0, y2: 0, class: cls }));
      legend.append(svg("text", { x: lx + 20, y: 4 }, label));
      lx += 30 + label.length * 5.6;
    });
    const compareLegend = svg("g", { visibility: "hidden", transform: "translate(0,-14)", "data-role": "compare-legend" });
    compareLegend.append(svg("line", { x1: 0, x2: 16, y1: 0, y2: 0, class: "compare-line" }));
    const compareText = svg("text", { x: 20, y: 4 }, "");
    compareLegend.append(compareText);
    legend.append(compareLegend);
    root.append(legend);
    // hover and click: the nearest trajectory index under the pointer
    const overlay = svg("rect", { x: padL, y: padT, width: W - padL - padR, height: H - padT - padB, class: "hover-overlay", "data-role": "hover" });
    root.append(overlay);
    const indexAt = (evt) => {
      const box = root.getBoundingClientRect();
      const x = (evt.clientX - box.left) * (W / box.width);
      const t = tmin + (x - padL) / (W - padL - padR) * (tmax - tmin);
      return indexOfTime(traj, t, dt);
    };
    overlay.addEventListener("mousemove", (evt) => setCursor(indexAt(evt), "margin"));
    overlay.addEventListener("click", (evt) => setCursor(indexAt(evt), "margin"));
    state.charts.margin = {
      cursor(i) {
        const p = traj[i];
        if (!p) return;
        cursor.setAttribute("x1", X(tOf(i))); cursor.setAttribute("x2", X(tOf(i)));
        if (typeof p.margin_m === "number") { dot.setAttribute("cx", X(tOf(i))); dot.setAttribute("cy", Y(p.margin_m)); }
        root.dataset.cursor = String(i);
      },
      exec(i, trace, live) {
        if (typeof i === "number" && traj[i]) {
          execCursor.setAttribute("x1", X(tOf(i))); execCursor.setAttribute("x2", X(tOf(i)));
          execCursor.setAttribute("visibility", "visible");
          execLabel.setAttribute("x", Math.min(X(tOf(i)) + 4, W - padR - 90));
          execLabel.textContent = "robot, t = " + Number(tOf(i)).toFixed(1) + " s";
          execLabel.setAttribute("visibility", "visible");
          root.dataset.execIndex = String(i);
        }
        if (trace && trace.length) {
          const sorted = trace.slice().sort((a, b) => a[0] - b[0]);
          const runs = [[sorted[0]]];
          for (let k = 1; k < sorted.length; k++) {
            if (tOf(sorted[k][0]) - tOf(sorted[k - 1][0]) > EXEC_GAP_S) runs.push([]);
            runs[runs.length - 1].push(sorted[k]);
          }
          execTrace.replaceChildren(...runs.map((run) => svg("polyline", { class: "exec-line", "data-role": "exec-run",
            points: run.map(([k, m]) => X(tOf(k)).toFixed(1) + "," + Y(Math.max(mmin, Math.min(mmax, m))).toFixed(1)).join(" ") })));
          const last = sorted[sorted.length - 1][0];
          root.dataset.execLastIndex = String(last);
          root.dataset.execLastX = X(tOf(last)).toFixed(1);
          root.dataset.execRuns = String(runs.length);
        }
      },
      /* The execution is over: a finished run needs no cursor; a stopped one says where the robot stopped. */
      execEnded(stateName, i) {
        if (stateName === "aborted" && typeof i === "number" && traj[i]) {
          execLabel.textContent = "robot stopped, t = " + Number(tOf(i)).toFixed(1) + " s";
        } else {
          execCursor.setAttribute("visibility", "hidden");
          execLabel.setAttribute("visibility", "hidden");
        }
      },
      compare(other, label) {
        const pts = other.map((p, k) => [typeof p.t === "number" ? p.t : k * dt, p.margin_m])
          .filter((p) => typeof p[1] === "number" && p[0] <= tmax + 1e-9);
        compareLine.setAttribute("points", pts.map(([t, m]) => X(t).toFixed(1) + "," + Y(Math.max(mmin, Math.min(mmax, m))).toFixed(1)).join(" "));
        const cut = other.length && other[other.length - 1].t > tmax + 1e-9;
        compareText.textContent = label + (cut ? " (its first " + tmax.toFixed(1) + " s)" : "");
        compareLegend.setAttribute("visibility", "visible");
        root.dataset.compare = "drawn";
      },
    };
  }

  function indexOfTime(traj, t, dt) {
    if (dt > 0) return Math.max(0, Math.min(traj.length - 1, Math.round((t - (traj[0].t || 0)) / dt)));
    let lo = 0, hi = traj.length - 1;
    while (lo < hi) { const mid = (lo + hi) >> 1; if (traj[mid].t < t) lo = mid + 1; else hi = mid; }
    return lo;
  }

  function renderSegments(segments, traj) {
    const body = $("segments").querySelector("tbody");
    const P = state.plan;
    body.replaceChildren(...segments.map((seg, i) => {
      const tr = el("tr", { "data-segment": i, "tabindex": "0" });
      let worst = seg.first, best = Infinity;
      for (let k = seg.first; k <= seg.last && k < traj.length; k++) {
        const m = traj[k].margin_m;
        if (typeof m === "number" && m < best) { best = m; worst = k; }
      }
      tr.dataset.worst = String(worst);
      const t0 = traj[seg.first] ? traj[seg.first].t : null, t1 = traj[seg.last] ? traj[seg.last].t : null;
      if (P && P.worst >= seg.first && P.worst <= seg.last) tr.classList.add("has-worst");
      tr.append(el("td", {}, i), el("td", {}, seg.kind), el("td", {}, seg.hand),
        el("td", {}, seg.first + "-" + seg.last),
        el("td", {}, t0 === null ? "-" : Number(t0).toFixed(2) + "-" + Number(t1).toFixed(2)),
        el("td", {}, best < Infinity ? mm(best) : "-"), el("td", { class: "exec-min" }, "-"));
      // hover shows the segment's worst moment in every view; a click keeps it there
      tr.addEventListener("mouseenter", () => setCursor(worst, "segment"));
      tr.addEventListener("click", () => setCursor(worst, "segment"));
      tr.addEventListener("keydown", (e) => { if (e.key === "Enter") setCursor(worst, "segment"); });
      return tr;
    }));
  }

  /* A survey as the CLI shows it: R with its 95 % interval and seed count per configuration, the recommendation,
     and a tie where intervals overlap (the recommendation is then not decided by the survey). */
  function renderSurvey(survey) {
    const rows = survey.rows || [];
    const ties = new Set(survey.indistinguishable || []);
    const ci = (row) => Array.isArray(row.ratio_ci95) && row.ratio_ci95.length === 2 ? row.ratio_ci95 : null;
    const body = $("survey-table").querySelector("tbody");
    body.replaceChildren(...rows.map((row) => {
      const tr = el("tr", { "data-hands": row.hands });
      const rec = row.hands === survey.recommended;
      if (rec) tr.classList.add("recommended");
      const interval = ci(row);
      const swatch = el("span", { class: "swatch", style: "display:inline-block;width:10px;height:10px;margin-right:4px;background:" + (HANDS_COLOURS[row.hands] || "#999") });
      const hands = el("td", {}, "");
      hands.append(swatch, row.hands);
      tr.append(hands, el("td", {}, row.stable), el("td", {}, row.unstable),
        el("td", {}, row.ratio === null || row.ratio === undefined ? "- (" + (row.reason || "no plan") + ")" : Number(row.ratio).toFixed(4)),
        el("td", { "data-role": "ci" }, interval ? "[" + interval[0].toFixed(4) + ", " + interval[1].toFixed(4) + "]" : "-"),
        el("td", { "data-role": "seeds" }, row.seeds === undefined ? "-" : String(row.seeds) + (row.converged === false ? " (not converged)" : "")),
        el("td", {}, rec ? (ties.size ? "recommended (tie)" : "recommended") : ties.has(row.hands) ? "tie with " + survey.recommended : ""));
      return tr;
    }));
    const best = rows.find((r) => r.hands === survey.recommended);
    const bestCi = best && ci(best);
    $("survey-summary").textContent = !best ? "No configuration could be surveyed." :
      "Recommended: " + best.hands + " (R " + Number(best.ratio).toFixed(4) + (bestCi ? ", 95 % interval [" + bestCi[0].toFixed(4) + ", " + bestCi[1].toFixed(4) + "]" : "") +
      (best.seeds !== undefined ? ", " + best.seeds + " seeds" : "") + ")" +
      (ties.size ? "; a tie with " + [...ties].join(", ") + ": their intervals overlap, so the survey does not tell them apart (the tie order picked " + best.hands + ")." : "; no other configuration's interval overlaps it.");
    $("survey-summary").dataset.tie = String(ties.size > 0);
    const W = 560, H = 280, padL = 46, padB = 40, padT = 16, padR = 10;
    const root = chartFrame($("survey-chart"), W, H, "Ratio of stable states per hand configuration, with 95 % intervals");
    const n = Math.max(rows.length, 1);
    const slot = (W - padL - padR) / n;
    const lo = Math.min(0, ...rows.map((r) => (ci(r) ? ci(r)[0] : (typeof r.ratio === "number" ? r.ratio : 0)))) ;
    const Y = (r) => H - padB - ((r - lo) / (1 - lo || 1)) * (H - padT - padB);
    for (const r of [0, 0.25, 0.5, 0.75, 1]) {
      root.append(svg("line", { x1: padL, x2: W - padR, y1: Y(r), y2: Y(r), class: "gridline" }));
      root.append(svg("text", { x: padL - 4, y: Y(r) + 4, "text-anchor": "end" }, r.toFixed(2)));
    }
    rows.forEach((row, i) => {
      const x = padL + i * slot + slot * 0.2;
      const ratio = typeof row.ratio === "number" ? row.ratio : 0;
      const rec = row.hands === survey.recommended;
      const bar = svg("rect", { x, y: Y(ratio), width: slot * 0.6, height: Y(0) - Y(ratio),
        class: "bar" + (rec ? " bar-recommended" : "") + (ties.has(row.hands) ? " bar-tie" : "") + (typeof row.ratio === "number" ? "" : " bar-none"),
        "data-hands": row.hands });
      if (typeof row.ratio === "number") bar.setAttribute("style", "fill:" + (HANDS_COLOURS[row.hands] || "#999"));
      root.append(bar);
      const interval = ci(row);
      const cx = x + slot * 0.3;
      if (interval) {  // the interval as an error bar; its label sits beside it, never across it
        root.append(svg("line", { x1: cx, x2: cx, y1: Y(interval[0]), y2: Y(interval[1]), class: "ci-bar", "data-role": "ci-bar", "data-hands": row.hands }));
        for (const v of interval) root.append(svg("line", { x1: cx - 5, x2: cx + 5, y1: Y(v), y2: Y(v), class: "ci-bar" }));
      }
      root.append(svg("text", { x: cx + 8, y: Y(interval ? interval[1] : ratio) - 4, "text-anchor": "start" },
        typeof row.ratio === "number" ? row.ratio.toFixed(3) : "n/a"));
      root.append(svg("text", { x: cx, y: H - padB + 16, "text-anchor": "middle" }, row.hands + (rec ? " *" : "")));
    });
    root.append(svg("text", { x: 12, y: H / 2, "text-anchor": "middle", transform: "rotate(-90 12 " + H / 2 + ")" }, "R = C / (C + U)"));
    root.append(svg("text", { x: W - padR, y: H - 6, "text-anchor": "end" }, "* recommended; bars: 95 % interval" + (ties.size ? "; dashed: a tie" : "")));
  }

  // ------------------------------------------------------------- execution
  /* Execution progress: the index the controller reports over the plan's points. */
  function execFraction(job) {
    const ex = state.exec;
    if (!ex || ex.jobId !== job.id || !ex.points) return 0;
    return Math.max(0, Math.min(1, (ex.index || 0) / Math.max(ex.points - 1, 1)));
  }

  /* The execution bar shows the job the robot is executing: the one shown if it is, else the one the
     job list says is (an operator looking at another job still has Stop at hand). */
  function updateExecBar(job) {
    const bar = $("exec-bar");
    if (job && !EXECUTING.has(job.state) && state.exec && state.exec.jobId === job.id) {
      state.exec.live = false;
      finishExecCursor(job);
    }
    const listed = state.runningJob && !(job && state.runningJob.id === job.id) ? state.runningJob : null;  // the detail is fresher
    const running = job && EXECUTING.has(job.state) ? job : listed;
    const executing = !!running;
    bar.hidden = !executing;
    document.body.classList.toggle("with-exec-bar", executing);  // room below the page for the bar
    if (!executing) return;
    const stop = $("btn-stop");
    const why = refusal("stop", running);
    stop.hidden = why === HIDE;
    stop.disabled = why !== null && why !== HIDE;
    stop.dataset.jobId = running.id;
    $("exec-job").textContent = shortId(running.id);
    $("exec-message").textContent = running.message || running.state;
    $("exec-progress-bar").style.width = Math.round(execFraction(running) * 100) + "%";
  }

  /* Stop the job the execution bar shows (it may not be the job shown in the details). */
  async function stopFromBar() {
    const id = $("btn-stop").dataset.jobId;
    if (state.job && state.job.id === id) return act("stop");
    try {
      await api("POST", "/v1/jobs/" + encodeURIComponent(id) + "/stop", { reason: "operator console" });
      refreshJobs();
    } catch (err) {
      showBanner("Stop of job " + shortId(id) + " failed: " + (err.detail || err.message), "error");
    }
  }

  function ensureExec(job) {
    if (!state.exec || state.exec.jobId !== job.id) {
      const n = state.plan ? state.plan.traj.length : 0;
      state.exec = { jobId: job.id, index: 0, points: n, trace: [], live: true, segMin: {}, segPlanMin: {}, segCount: {} };
    }
    return state.exec;
  }

  /* What a bridge event means to an operator (the dispatcher's event names are not shown raw). */
  function bridgeMessage(job, name, d) {
    const ex = ensureExec(job);
    if (name === "dispatching" && typeof d.points === "number") ex.points = d.points;
    const of = () => "point " + (ex.index || 0) + " of " + Math.max((ex.points || 1) - 1, 0) +
      (state.plan && state.plan.traj[ex.index] ? " (t = " + Number(state.plan.traj[ex.index].t).toFixed(1) + " s)" : "");
    switch (name) {
      case "gate": {
        const text = d.passed ? "safety gate passed (" + (d.samples || 0) + " samples checked)" :
          "safety gate vetoed: " + (d.check || "?") + (d.point_index !== undefined && d.point_index !== null ? " at point " + d.point_index : "") + ": " + (d.message || "");
        return text;
      }
      case "dispatching": return "sending the plan to the controller (" + (d.segments || "?") + " segments)";
      case "executing":
        if (typeof d.index === "number") { ex.index = d.index; followExec(null); }
        return "robot moving: " + of();
      case "robot_state":
        if (typeof d.index === "number") ex.index = d.index;
        followExec(d);
        return "robot moving: " + of();
      case "segment":
        if (typeof d.segment_index === "number" && typeof d.segment_count === "number") {
          return "robot moving: " + of() + "; segment " + (d.segment_index + 1) + " of " + d.segment_count + " sent";
        }
        return null;  // acknowledgements and re-sends keep the last message
      case "balance": {  // the physics plant's balance: the CoP drawn live beside the planned ZMP
        const chart = state.charts && state.charts.com;
        if (chart && chart.cop && Array.isArray(d.cop) && typeof d.cop[0] === "number") chart.cop(d.cop[0], d.cop[1]);
        return null;
      }
      case "controller":
        return "controller reports " + (d.status || "?") + (d.reason ? ": " + d.reason : "");
      case "stop_sent": return "stop sent to the controller" + (d.reason ? " (" + d.reason + ")" : "");
      case "finished": return "execution finished: " + (d.status || "") + (d.reason ? " (" + d.reason + ")" : "");
      default: return null;
    }
  }

  /* Move the execution cursor; with a measured joint state, draw the robot there and its executed margin. */
  function followExec(d, replay) {
    const ex = state.exec;
    const P = state.plan;
    if (!ex || !P) return;
    if (!replay) ex.live = true;
    const i = Math.max(0, Math.min(P.traj.length - 1, ex.index || 0));
    let measured = null;
    const drawn = window.regrasp3d && $("view3d").dataset.status === "drawn";
    if (d && Array.isArray(d.q) && Array.isArray(d.joint_names) && drawn) {
      measured = window.regrasp3d.setMeasured(d.joint_names, d.q, i);
      ex.measured = true;
      ex.last = { joint_names: d.joint_names, q: d.q, index: i };
    } else if (!replay && !ex.measured && drawn) {
      window.regrasp3d.setIndex(i);  // no measured joints yet: the planned pose at the reported index
    }
    if (measured && isFinite(measured.margin_m)) {
      ex.trace.push([i, measured.margin_m]);
      const seg = P.segOf[i];
      if (seg >= 0) {
        ex.segMin[seg] = Math.min(ex.segMin[seg] === undefined ? Infinity : ex.segMin[seg], measured.margin_m);
        const planned = P.traj[i].margin_m;
        if (typeof planned === "number") ex.segPlanMin[seg] = Math.min(ex.segPlanMin[seg] === undefined ? Infinity : ex.segPlanMin[seg], planned);
        ex.segCount[seg] = (ex.segCount[seg] || 0) + 1;
      }
    }
    updateExecSegments();
    if (state.charts && state.charts.margin) state.charts.margin.exec(i, ex.trace);
    if (state.charts && state.charts.com) state.charts.com.exec(i, measured);
    $("view3d").dataset.execIndex = String(i);
  }

  /* Each segment's executed minimum beside the planned minimum over the same measured points, and whether
     the segment is still running (or was cut short by a stop): a partial minimum is never shown as final. */
  function updateExecSegments() {
    const ex = state.exec, P = state.plan, job = state.job;
    if (!ex || !P || !job || ex.jobId !== job.id) return;
    const at = ex.index || 0;
    for (const [key, value] of Object.entries(ex.segMin)) {
      const seg = Number(key), s = P.doc.segments[seg];
      const cell = $("segments").querySelector('tbody tr[data-segment="' + seg + '"] td.exec-min');
      if (!cell || !s) continue;
      const running = EXECUTING.has(job.state) && at >= s.first && at <= s.last;
      const cut = job.state === "aborted" && at >= s.first && at < s.last;
      const n = ex.segCount[seg] || 0;
      cell.textContent = mm(value) + " (planned " + mm(ex.segPlanMin[seg]) + " at the same " + n + " point" + (n === 1 ? "" : "s") + ")" +
        (running ? ", running" : cut ? ", partial: stopped" : "");
      cell.classList.toggle("seg-running", running || cut);
      cell.dataset.status = running ? "running" : cut ? "partial" : "final";
    }
  }

  function finishExecCursor(job) {
    const ex = state.exec;
    if (!ex || ex.jobId !== job.id || !TERMINAL.has(job.state)) return;
    if (state.charts && state.charts.margin && state.charts.margin.execEnded) state.charts.margin.execEnded(job.state, ex.index);
    updateExecSegments();
  }

  // ------------------------------------------------------------ comparison
  /* The site's floor: what the service's risk card says, else the built-in default (and the page says which). */
  function siteFloor() {
    const card = state.risk && state.risk.planning;
    const given = card && (card.margin_floor_m ?? (card.policy && card.policy.margin_floor_m));
    return typeof given === "number" ? { value: given, source: "the site's policy" } : { value: DEFAULT_FLOOR_M, source: "the built-in floor" };
  }

  /* The threshold of the task a plan belongs to: its own, unless it is a comparison (then the scenario's). */
  function taskThreshold(job, plan) {
    const own = Number((plan && plan.threshold_m) || 0);
    if (!job || !job.comparison) return own;
    const req = job.request || {};
    if (req.scenario && typeof req.scenario === "object" && typeof req.scenario.threshold_m === "number") return req.scenario.threshold_m;
    const entry = state.catalogue && state.catalogue.scenarios.find((x) => x.name === req.scenario);
    return entry ? entry.threshold_m : 0;
  }

  /* What every headroom figure is measured against: the task's threshold or the site's floor, the larger. */
  function safetyLine(job, plan) {
    const task = taskThreshold(job, plan), floor = siteFloor();
    return task >= floor.value ? { value: task, label: "the task's " + mm(task) + " mm threshold" }
      : { value: floor.value, label: floor.source + " of " + mm(floor.value) + " mm" };
  }

  function renderComparisonNote(job) {
    const note = $("comparison-note");
    note.hidden = !job.comparison;
    if (!job.comparison) return;
    const plan = job.result;
    const line = safetyLine(job, plan);
    const min = plan && typeof plan.min_margin_m === "number" ? plan.min_margin_m : null;
    note.textContent = "Comparison plan, not for the robot: planned at " + mm(plan ? plan.threshold_m : 0) +
      " mm, below the site's floor, so it is never approved or dispatched." +
      (min !== null ? " Its worst CoM margin is " + mm(min) + " mm: " + mm(Math.abs(min - line.value)) + " mm " +
        (min < line.value ? "below " : "above ") + line.label + "." : "");
    note.dataset.below = String(min !== null && min < line.value);
  }

  /* The second plan drawn beside the one shown: for a plan, its comparison; for a comparison, the task's plan. */
  async function loadCompare(job, risk) {
    let otherId = null, label = null;
    if (!job.comparison && risk && risk.unconstrained && risk.unconstrained.job_id) {
      otherId = risk.unconstrained.job_id;
      label = "comparison at 0 mm (job " + shortId(otherId) + "), not for the robot";
    } else if (job.comparison) {
      try {
        const list = await api("GET", "/v1/jobs?kind=plan&limit=200");
        const same = (r) => JSON.stringify(Object.entries(r || {}).filter(([k]) => k !== "threshold_m" && k !== "time_limit_s").sort());
        const mine = same(job.request);
        const task = (list.jobs || []).find((j) => j.id !== job.id && !j.comparison && j.plan_sha256 && same(j.request) === mine);
        if (task) { otherId = task.id; label = "the task's plan (job " + shortId(task.id) + ")"; }
      } catch (err) { return; }
    }
    if (!otherId || (state.compare && state.compare.jobId === otherId && state.compare.forJob === job.id)) return;
    try {
      const other = await api("GET", "/v1/jobs/" + encodeURIComponent(otherId));
      if (!state.job || state.job.id !== job.id || !other.result || !Array.isArray(other.result.trajectory)) return;
      state.compare = { jobId: otherId, forJob: job.id, label, traj: other.result.trajectory };
      drawCompare();
    } catch (err) { /* the comparison is extra: the plan's own view stands without it */ }
  }

  function drawCompare() {
    const c = state.compare;
    if (!c || !state.job || c.forJob !== state.job.id) return;
    if (state.charts && state.charts.margin && state.charts.margin.compare) state.charts.margin.compare(c.traj, c.label);
    if (state.charts && state.charts.com && state.charts.com.compare) state.charts.com.compare(c.traj, c.label);
    if (window.regrasp3d && $("view3d").dataset.status === "drawn") window.regrasp3d.showComparison(c.traj);
  }

  // -------------------------------------------------------------- recovery
  /* The robot's measured states of an execution, from the job's event history (robot_state events). */
  async function executionHistory(jobId) {
    const r = await fetch("/v1/jobs/" + encodeURIComponent(jobId) + "/events?follow=false",
      { headers: { "Authorization": "Bearer " + state.token, "Accept": "text/event-stream" } });
    if (!r.ok) return [];
    const text = await r.text();
    const out = [];
    for (const block of text.split("\n\n")) {
      const ev = parseSse(block);
      const p = ev && ev.payload;
      if (!p || ev.event !== "bridge" || !p.data || p.data.event !== "robot_state") continue;
      const d = p.data.payload || {};
      if (Array.isArray(d.samples)) {
        for (const s of d.samples) out.push({ joint_names: d.joint_names, q: s.q, index: s.index, stamp: s.stamp });
      } else if (Array.isArray(d.q)) out.push(d);
    }
    return out;
  }

  /* After an execution ended (stopped, or vetoed at its start), show where the robot is and offer the way back. */
  function renderRecovery(job) {
    const box = $("recovery");
    const d = state.risk && state.risk.job_id === job.id ? state.risk.dispatch : null;
    const startVeto = job.state === "rejected" && ((d && d.check === "start_state") || /start.?state/i.test((job.error && job.error.message) || ""));
    const show = job.state === "aborted" || startVeto;
    box.hidden = !show;
    if (!show) return;
    box.dataset.reason = startVeto ? "start-state" : "aborted";
    $("recovery-text").textContent = startVeto
      ? "The robot is not where this plan starts, so the safety gate refused it. The way out: plan the way back " +
        "(a recover job from the robot's measured joints to its stance posture), have it approved and dispatch it; then plan this task again."
      : "The execution was stopped. The translucent orange robot in the 3D view is the robot's last measured pose; " +
        "the grey one is the plan. Plan the way back before the next plan: every plan starts from the stance posture.";
    const button = $("btn-recover");
    const why = state.me === undefined ? "who you are is not known yet" : (state.me !== null && !hasRole("operator")) ? "planning the way back needs the role 'operator'" : null;
    button.disabled = why !== null || state.busy;
    button.title = why || "submit a recover job: plan from the measured joints back to the stance posture";
    if (job.state === "aborted" && state.ghostFor !== job.id) showMeasuredGhost(job);
  }

  async function showMeasuredGhost(job) {
    state.ghostFor = job.id;
    let last = null;
    if (state.exec && state.exec.jobId === job.id && state.exec.last) last = state.exec.last;
    let history = [];
    try { history = await executionHistory(job.id); } catch (err) { history = []; }
    if (history.length) last = history[history.length - 1];
    if (!state.job || state.job.id !== job.id || !last) return;
    const place = () => {
      if (!window.regrasp3d || $("view3d").dataset.status !== "drawn") return false;
      replayExecution(job, history);
      window.regrasp3d.setIndex(state.cursor);  // the plan's robot back in its own colour, at the cursor
      const ok = window.regrasp3d.showGhost(last.joint_names, last.q);
      $("view3d").dataset.ghost = ok ? "measured" : "";
      // A state measured after the stream ended (the robot holding) has no sample index: show the last one reached.
      const reached = [...history].reverse().find((d) => typeof d.index === "number");
      const index = typeof last.index === "number" ? last.index : reached ? reached.index : null;
      $("recovery").dataset.measuredIndex = index === null ? "" : String(index);
      return true;
    };
    if (!place()) $("view3d").addEventListener("regrasp3d:drawn", place, { once: true });
  }

  /* The executed margin of a finished execution, from its measured states (when the page did not watch it live). */
  function replayExecution(job, history) {
    if (!history.length || !state.plan) return;
    const ex = ensureExec(job);
    if (ex.trace.length >= history.length) return;
    ex.trace = []; ex.segMin = {}; ex.segPlanMin = {}; ex.segCount = {};
    for (const d of history) { if (typeof d.index === "number") ex.index = d.index; followExec(d, true); }
    ex.live = false;
    if (window.regrasp3d) window.regrasp3d.setIndex(state.cursor);
    finishExecCursor(job);
  }

  async function planWayBack() {
    const job = state.job;
    const robot = (state.health && state.health.robot_id) || (state.plan && state.plan.doc.robot && state.plan.doc.robot.name) || "hrp5p";
    $("recovery-result").textContent = "";
    try {
      const rec = await api("POST", "/v1/jobs", { kind: "recover", request: { robot } });
      $("recovery-result").textContent = "submitted as job " + shortId(rec.id) + ": it is planned, then approved and dispatched like any plan";
      $("recovery-result").dataset.jobId = rec.id;
      refreshJobs();
      selectJob(rec.id);
    } catch (err) {
      $("recovery-result").textContent = "not submitted: " + (err.detail || err.message);
      if (job) showProblem(err);
    }
  }

  // ----------------------------------------------------------------- reject
  /* Reject asks first, with a reason that is required (it is stored with the job and audited). */
  function askRejectReason(job) {
    const dialog = $("reject-dialog");
    const text = $("reject-reason");
    text.value = "";
    $("reject-hint").hidden = true;
    dialog.dataset.jobId = job.id;
    return new Promise((resolve) => {
      const form = $("reject-form");
      const onSubmit = (e) => {
        const ok = e.submitter && e.submitter.value === "ok";
        if (ok && !text.value.trim()) { e.preventDefault(); $("reject-hint").hidden = false; text.focus(); return; }
      };
      form.addEventListener("submit", onSubmit);
      dialog.addEventListener("close", () => {
        form.removeEventListener("submit", onSubmit);
        resolve(dialog.returnValue === "ok" && text.value.trim() ? text.value.trim() : null);
      }, { once: true });
      dialog.returnValue = "";
      dialog.showModal();
      text.focus();
    });
  }

  // --------------------------------------------------------------- confirm
  /* Approve and dispatch ask first, showing the plan's hash prefix (what the approval binds to). */
  function confirmAction(action, job) {
    const dialog = $("confirm");
    const sha = job.plan_sha256 || (job.approval && job.approval.plan_sha256) || "";
    const risk = state.risk && state.risk.job_id === job.id ? state.risk.planning : null;
    const headroom = risk && risk.com_margin ? " Worst CoM margin headroom " + mm(risk.com_margin.headroom_m) + " mm at t = " +
      Number(risk.com_margin.t).toFixed(2) + " s." : "";
    $("confirm-title").textContent = action === "approve" ? "Approve this plan?" : "Dispatch this plan to the robot?";
    $("confirm-text").textContent = action === "approve"
      ? "Your approval binds to this exact plan and expires after the service's approval time." + headroom
      : "The robot will move (101 kg). The safety gate rechecks the plan first; keep the Stop button in reach." + headroom;
    $("confirm-hash").textContent = sha.slice(0, 12);
    $("confirm-ok").textContent = action === "approve" ? "Approve " + sha.slice(0, 8) : "Dispatch " + sha.slice(0, 8);
    dialog.dataset.action = action;
    return new Promise((resolve) => {
      dialog.addEventListener("close", () => resolve(dialog.returnValue === "ok"), { once: true });
      dialog.returnValue = "";
      dialog.showModal();
      $("confirm-cancel").focus();
    });
  }

  // ------------------------------------------------------------------ risk
  const HAS_PLAN = new Set(["planned", "approved", "dispatching", "executing", "succeeded", "aborted", "rejected"]);

  async function loadRisk(job) {
    const box = $("risk-card");
    if ((job.kind !== "plan" && job.kind !== "recover") || !HAS_PLAN.has(job.state) || !job.plan_sha256) { box.hidden = true; return; }
    const key = job.id + ":" + job.state;
    if (state.riskFor === key) {
      // Loaded (or loading) already: a re-render of the same job keeps the card on screen.
      if (state.risk && state.risk.job_id === job.id && box.hidden) renderRisk(state.risk);
      return;
    }
    state.riskFor = key;
    try {
      const risk = await api("GET", "/v1/jobs/" + encodeURIComponent(job.id) + "/risk");
      if (!state.job || state.job.id !== job.id) return;
      state.risk = risk;
      renderRisk(risk);
      renderRecovery(state.job);
      renderComparisonNote(state.job);
      loadCompare(state.job, risk);
    } catch (err) {
      if (err.status === 404 && !(state.job && state.job.id === job.id)) return;
      box.hidden = false;
      $("risk-verdict").textContent = "risk card unavailable: " + (err.detail || err.message);
      $("risk-verdict").className = "risk-verdict warn";
      if (err.status === 404) state.riskFor = null;
    }
  }

  function momentText(m) {
    if (!m || m.t === null || m.t === undefined) return "-";
    const seg = m.segment ? ", segment " + m.segment.index + " " + m.segment.kind + " (" + m.segment.hand + ")" : "";
    return "t = " + Number(m.t).toFixed(2) + " s (point " + m.point + seg + ")";
  }

  function renderRisk(risk) {
    const box = $("risk-card");
    box.hidden = false;
    const card = risk.planning;
    const verdict = $("risk-verdict");
    const facts = $("risk-facts");
    facts.replaceChildren();
    const add = (label, value, attrs) => {
      facts.append(el("dt", {}, label));
      const dd = el("dd", attrs || {}, value);
      facts.append(dd);
      return dd;
    };
    if (!card) {
      verdict.textContent = "no risk card for this plan";
      verdict.className = "risk-verdict warn";
    } else if (card.error) {
      verdict.textContent = card.error;
      verdict.className = "risk-verdict warn";
    } else {
      const g = card.gate || {};
      const job = state.job && state.job.id === risk.job_id ? state.job : null;
      verdict.textContent = job && job.comparison
        ? "comparison plan: not for the robot (never approved or dispatched); the gate's dry run below measures it against " + safetyLine(job, job.result).label
        : g.passed
        ? "gate dry run: PASS (" + (g.samples || 0) + " samples, " + (g.checks_passed || []).length + " checks; approval, hash and start state are checked at dispatch)"
        : "gate dry run: VETO [" + g.check + "] " + momentText(g.failed_at) + ": " + g.message;
      verdict.className = "risk-verdict " + (job && job.comparison ? "warn" : g.passed ? "ok" : "bad");
      verdict.dataset.passed = String(!!g.passed);
      const com = card.com_margin;
      if (com) {
        // Headroom against the task's threshold or the site's floor, whichever is larger; never the plan's own
        // threshold when that was lowered (a comparison).
        const line = job ? safetyLine(job, job.result || { threshold_m: card.threshold_m }) : { value: card.threshold_m, label: "the " + mm(card.threshold_m) + " mm threshold" };
        const line2 = line.value >= card.threshold_m ? line : { value: card.threshold_m, label: "the " + mm(card.threshold_m) + " mm threshold" };
        const headroom = com.min_margin_m - line2.value;
        const dd = add("Worst CoM margin", mm(com.min_margin_m) + " mm, headroom " + mm(headroom) + " mm " +
          (headroom < 0 ? "(below) " : "above ") + line2.label + ", at " + momentText(com) + ", held by " + (com.hand || "none"),
          { "data-role": "risk-worst", "data-point": String(com.point), "data-headroom-mm": (headroom * 1000).toFixed(1) });
        if (headroom < 0.005) dd.classList.add("tight");
        const link = el("button", { type: "button", class: "secondary small", "data-role": "risk-goto" }, "show");
        link.addEventListener("click", () => setCursor(com.point, "risk"));
        dd.append(" ", link);
      }
      if (card.zmp) add("Worst ZMP margin", mm(card.zmp.min_margin_m) + " mm inside the support polygon, at " + momentText(card.zmp));
      const phys = card.physics;
      if (phys) {
        const rep = phys.report || {}, at = phys.at || {};
        const where = typeof at.t === "number" ? " at t = " + at.t.toFixed(2) + " s" + (at.segment ? " (" + at.segment.kind + ", " + at.segment.hand + ")" : "") : "";
        const text = phys.error ? phys.error
          : rep.fault ? (rep.fell ? "FELL" : "FAULT") + " in the physics twin: " + rep.fault.kind + where + " (" + rep.fault.detail + ")"
          : "stood in the physics twin; smallest CoP margin " + mm(rep.min_cop_margin_m) + " mm" + where +
            (typeof rep.cop_margin_ratio === "number" ? ", " + rep.cop_margin_ratio.toFixed(2) + " of the plan's CoM margin" : "");
        const dd = add("Physics dry run", text, { "data-role": "risk-physics", "data-stood": String(!!phys.stood) });
        if (!phys.stood) dd.classList.add("tight");
      }
      if (card.effort) add("Effort headroom", (100 * card.effort.headroom).toFixed(1) + " % (peak ratio " + card.effort.max_ratio.toFixed(3) +
        " at " + momentText(card.effort) + "; the planner's static torques)");
      else add("Effort headroom", "no effort limits in this plan");
    }
    const free = risk.unconstrained;
    if (free) {
      add("Against 0 mm", "the unconstrained plan (job " + shortId(free.job_id) + ") reaches " + mm(free.unconstrained_min_margin_m) +
        " mm" + (free.unconstrained_breaks_threshold ? ", below the threshold" : ", within the threshold") +
        (free.plans_differ ? "; the constrained motion differs" : "; the same motion"));
    } else if (!(state.job && state.job.comparison)) {
      const dd = add("Against 0 mm", "no 0 mm comparison of this task in the store");
      const job = state.job;
      if (job && job.id === risk.job_id && (state.me === null || hasRole("planner")) && job.request) {
        const b = el("button", { type: "button", class: "secondary small", "data-role": "plan-unconstrained" }, "plan it at 0 mm");
        b.title = "submit the same request with threshold 0 (the unconstrained planner): a comparison, drawn beside this plan and never sent to the robot";
        b.addEventListener("click", () => {
          const request = Object.assign({}, job.request, { threshold_m: 0 });
          api("POST", "/v1/jobs", { kind: "plan", request })
            .then((other) => { b.replaceWith(" submitted as job " + shortId(other.id) + " (a comparison, not for the robot); it is drawn beside this plan when it is planned"); refreshJobs(); })
            .catch((err) => { b.replaceWith(" not submitted: " + (err.detail || err.message)); });
        });
        dd.append(" ", b);
      }
    }
    const dispatch = $("risk-dispatch");
    const d = risk.dispatch;
    dispatch.hidden = !d;
    if (d) {
      const seg = d.segment ? ", segment " + d.segment.index + " " + d.segment.kind + " (" + d.segment.hand + ")" : "";
      dispatch.textContent = d.passed ? "gate at dispatch: PASS (" + (d.samples || 0) + " samples)"
        : "gate at dispatch: VETO [" + d.check + "]" + (d.sample_index !== null && d.sample_index !== undefined
          ? " at sample " + d.sample_index + " (point " + d.point_index + ", t = " + Number(d.t).toFixed(3) + " s" + seg + ")" : "") + ": " + d.message;
      if (!d.passed && d.check === "start_state") dispatch.textContent += " The way out: plan the way back (below), then plan again.";
      dispatch.className = "risk-dispatch " + (d.passed ? "ok" : "bad");
      dispatch.dataset.check = d.check || "";
    }
  }

  // ------------------------------------------------------------- catalogue
  async function loadCatalogue() {
    if (!state.token || state.catalogue) return;
    try {
      state.catalogue = await api("GET", "/v1/catalogue");
    } catch (err) {
      return;  // the form keeps a free-text fallback below
    }
    const c = state.catalogue;
    const fill = (id, values, keepFirst) => {
      const sel = $(id);
      const first = keepFirst ? sel.querySelector("option") : null;
      sel.replaceChildren(...(first ? [first] : []), ...values.map((v) => el("option", { value: v }, v)));
    };
    fill("submit-scenario", c.scenarios.map((s) => s.name), false);
    fill("submit-stance", c.stances, true);
    fill("submit-hands", c.hands, true);
    fill("submit-robot", c.robots, true);
    const upright = c.scenarios.find((s) => s.name === "upright");
    if (upright) $("submit-scenario").value = "upright";
    showScenarioDefaults();
  }

  function showScenarioDefaults() {
    const c = state.catalogue;
    const s = c && c.scenarios.find((x) => x.name === $("submit-scenario").value);
    if (!s) { $("submit-defaults").textContent = ""; return; }
    $("submit-threshold").placeholder = "scenario's: " + (s.threshold_m * 1000).toFixed(0);
    $("submit-seed").placeholder = "scenario's: " + s.seed;
    $("submit-time-limit").placeholder = s.time_limit_s ? "scenario's: " + s.time_limit_s : "scenario's";
    $("submit-stance").options[0].textContent = "scenario's own (" + s.stance + ")";
    $("submit-hands").options[0].textContent = "scenario's own (" + s.hands + ")";
    $("submit-robot").options[0].textContent = "scenario's own (" + s.robot + ")";
    $("submit-defaults").textContent = "Empty fields keep the scenario's own values: " + s.robot + ", " + s.stance + " stance, threshold " +
      (s.threshold_m * 1000).toFixed(0) + " mm, hands " + s.hands + ", seed " + s.seed + ", " + s.object_shape + " of " + s.object_mass_kg + " kg.";
  }

  function showSubmitProblem(err) {
    const box = $("submit-problem");
    if (!err) { box.hidden = true; box.textContent = ""; return; }
    const status = err.status ? (err.status + " " + (err.title || "")) : "error";
    box.textContent = "Not submitted. " + status.trim() + ": " + (err.detail || err.message);
    box.hidden = false;
  }

  // ------------------------------------------------------------------ start
  function submitJob(e) {
    e.preventDefault();
    const kind = $("submit-kind").value;
    const request = { scenario: $("submit-scenario").value };
    for (const [id, key] of [["submit-stance", "stance"], ["submit-hands", "hands"], ["submit-robot", "robot"]]) {
      if ($(id).value) request[key] = $(id).value;
    }
    const thr = $("submit-threshold").value;
    if (thr !== "") request.threshold_m = Number(thr) / 1000;
    const seed = $("submit-seed").value;
    if (seed !== "") request.seed = Number(seed);
    const limit = $("submit-time-limit").value;
    if (limit !== "") request.time_limit_s = Number(limit);
    showSubmitProblem(null);
    api("POST", "/v1/jobs", { kind, request })
      .then((job) => { refreshJobs(); selectJob(job.id); })
      .catch((err) => showSubmitProblem(err));  // a refused submission opens no job panel
  }

  function init() {
    $("token-form").addEventListener("submit", (e) => { e.preventDefault(); setToken($("token").value); });
    $("token-clear").addEventListener("click", () => { stopLive(); setToken(""); });
    $("jobs-refresh").addEventListener("click", refreshJobs);
    $("submit-form").addEventListener("submit", submitJob);
    $("submit-scenario").addEventListener("change", showScenarioDefaults);
    $("btn-audit").addEventListener("click", downloadAudit);
    for (const b of $("actions").querySelectorAll("button[data-action]")) {
      b.addEventListener("click", () => act(b.dataset.action));
    }
    $("btn-stop").addEventListener("click", stopFromBar);
    $("btn-recover").addEventListener("click", planWayBack);
    $("timeline").addEventListener("input", () => setCursor(Number($("timeline").value), "timeline"));
    $("timeline-play").addEventListener("click", playTimeline);
    $("view3d").addEventListener("regrasp:pick", (e) => setCursor(e.detail.index, "user-3d"));
    if (state.token) $("token").placeholder = "token set (" + state.token.slice(0, 6) + "...)";
    refreshHealth();
    loadIdentity();
    loadCatalogue();
    refreshJobs();
    setInterval(refreshHealth, 5000);
    setInterval(() => {
      if (!state.token || document.visibilityState === "hidden") return;
      refreshJobs();
      if (state.me === undefined && !state.identityPending) loadIdentity();  // a refused or failed look-up is retried
      if (!state.catalogue) loadCatalogue();
    }, LIST_REFRESH_MS);
  }

  // exposed for tests and the browser console
  window.regraspConsole = { shrinkConvex, parseSse, refusal, state, setCursor };
  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", init); else init();
})();
