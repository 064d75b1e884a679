/*
 * Regrasp operator console: plain JavaScript against the HTTP API of docs/contract.md section 5.
 * No build step, no external libraries: charts are inline SVG drawn here.
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
      tr.append(el("td", {}, job.kind));
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
    $("job-progress-bar").style.width = Math.round((job.progress || 0) * 100) + "%";
    $("job-kind").textContent = job.kind;
    $("job-submitter").textContent = job.submitter;
    $("job-message").textContent = job.message || "-";
    $("job-sha").textContent = job.plan_sha256 || "-";
    $("job-audit").textContent = job.audit_head || "-";
    const a = job.approval;
    $("job-approval").textContent = a ? (a.approved_by + " at " + fmtTime(a.approved_at) + ", expires " + fmtTime(a.expires_at)) : "-";
    $("job-error").textContent = job.error ? (job.error.code + ": " + job.error.message) : "-";
    updateButtons(job);
    // keep the list row in step
    const row = $("jobs").querySelector('tbody tr[data-job-id="' + job.id + '"]');
    if (row) {
      row.dataset.state = job.state;
      stateBadge(row.querySelector("span"), job.state);
      row.children[3].textContent = Math.round((job.progress || 0) * 100) + "%";
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
    const show = {
      approve: job.kind === "plan" && s === "planned",
      reject: job.kind === "plan" && s === "planned",
      dispatch: job.kind === "plan" && s === "approved",
      stop: EXECUTING.has(s),
      cancel: CANCELABLE.has(s),
    };
    for (const [action, fits] of Object.entries(show)) {
      const button = $("btn-" + action);
      const why = fits ? refusal(action, job) : HIDE;
      button.hidden = why === HIDE;
      button.disabled = state.busy || (why !== null && why !== HIDE);
      if (why !== null && why !== HIDE) { button.title = why; button.dataset.refused = why; }
      else { button.removeAttribute("title"); delete button.dataset.refused; }
    }
  }

  async function act(action) {
    const job = state.job;
    if (!job) return;
    showProblem(null);
    let body;
    if (action === "approve") body = job.plan_sha256 ? { plan_sha256: job.plan_sha256 } : {};
    if (action === "reject" || action === "stop" || action === "cancel") body = { reason: "operator console" };
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
      const d = (p.data && (p.data.payload || p.data)) || {};
      const seg = (typeof d.segment_index === "number" && typeof d.segment_count === "number")
        ? " " + (d.segment_index + 1) + "/" + d.segment_count : "";
      job.message = "robot: " + (p.message || (p.data && p.data.event) || "event") + seg;
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
    if (isPlan) renderPlan(result);
    if (isSurvey) renderSurvey(result);
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

  function renderPlan(plan) {
    const traj = plan.trajectory || [];
    const polygon = plan.support_polygon || [];
    const threshold = Number(plan.threshold_m || 0);
    const inner = shrinkConvex(polygon, threshold);
    drawComChart(polygon, inner, traj, threshold);
    drawMarginChart(traj, plan.segments || [], threshold, Number(plan.dt_s || 0));
    renderSegments(plan.segments || [], traj);
    const dur = traj.length ? traj[traj.length - 1].t : 0;
    $("plan-summary").textContent =
      "status " + plan.status + ", hands " + (plan.hands || "-") + ", " + traj.length + " points over " +
      Number(dur).toFixed(2) + " s, min margin " + mm(plan.min_margin_m) + " mm, threshold " + mm(threshold) + " mm" +
      (plan.failure ? ", failure " + plan.failure.code + ": " + plan.failure.message : "");
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
    const legend = svg("g", { class: "legend", transform: "translate(" + (pad + 6) + "," + 16 + ")" });
    const items = [["support", "support polygon"], ["threshold", "shrunk by " + mm(threshold) + " mm"], ["com-trace", "CoM trace"]];
    items.forEach(([cls, label], i) => {
      legend.append(svg("line", { x1: i * 140, x2: i * 140 + 18, y1: 0, y2: 0, class: cls + " legend-line" }));
      legend.append(svg("text", { x: i * 140 + 22, y: 4 }, label));
    });
    root.append(legend);
  }

  function drawMarginChart(traj, segments, threshold, dt) {
    const W = 460, H = 360, padL = 52, padR = 12, padT = 26, padB = 40;
    const root = chartFrame($("margin-chart"), W, H, "Stability margin over time");
    const pts = traj.filter((p) => typeof p.margin_m === "number").map((p, i) => [typeof p.t === "number" ? p.t : i * dt, p.margin_m]);
    if (!pts.length) { root.append(svg("text", { x: W / 2, y: H / 2, "text-anchor": "middle" }, "no margins")); return; }
    const tmin = pts[0][0], tmax = Math.max(pts[pts.length - 1][0], tmin + 1e-6);
    let mmin = Math.min(0, threshold, ...pts.map((p) => p[1])), mmax = Math.max(threshold, ...pts.map((p) => p[1]));
    mmax += (mmax - mmin) * 0.08 || 0.01;
    const X = (t) => padL + (t - tmin) / (tmax - tmin) * (W - padL - padR);
    const Y = (m) => H - padB - (m - mmin) / (mmax - mmin) * (H - padT - padB);
    // segment bands
    const palette = { transit: "band-transit", transfer: "band-transfer", handover: "band-handover", approach: "band-approach", retreat: "band-retreat" };
    segments.forEach((seg, i) => {
      const a = traj[seg.first], b = traj[seg.last];
      if (!a || !b) return;
      const x1 = X(a.t), x2 = X(b.t);
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
    root.append(svg("text", { x: 12, y: H / 2, "text-anchor": "middle", transform: "rotate(-90 12 " + H / 2 + ")" }, "margin (mm)"));
    root.append(svg("line", { x1: padL, x2: W - padR, y1: Y(threshold), y2: Y(threshold), class: "threshold-line", "data-role": "threshold-line" }));
    root.append(svg("text", { x: W - padR - 4, y: Y(threshold) - 5, "text-anchor": "end", class: "threshold-label" }, "threshold " + mm(threshold) + " mm"));
    root.append(svg("polyline", { points: pts.map((p) => X(p[0]).toFixed(1) + "," + Y(p[1]).toFixed(1)).join(" "), class: "margin-line", "data-role": "margin-line" }));
  }

  function renderSegments(segments, traj) {
    const body = $("segments").querySelector("tbody");
    body.replaceChildren(...segments.map((seg, i) => {
      const tr = el("tr");
      const span = traj.slice(seg.first, seg.last + 1).map((p) => p.margin_m).filter((m) => typeof m === "number");
      const t0 = traj[seg.first] ? traj[seg.first].t : null, t1 = traj[seg.last] ? traj[seg.last].t : null;
      tr.append(el("td", {}, i), el("td", {}, seg.kind), el("td", {}, seg.hand),
        el("td", {}, seg.first + "-" + seg.last),
        el("td", {}, t0 === null ? "-" : Number(t0).toFixed(2) + "-" + Number(t1).toFixed(2)),
        el("td", {}, span.length ? mm(Math.min(...span)) : "-"));
      return tr;
    }));
  }

  function renderSurvey(survey) {
    const rows = survey.rows || [];
    const body = $("survey-table").querySelector("tbody");
    body.replaceChildren(...rows.map((row) => {
      const tr = el("tr", { "data-hands": row.hands });
      const rec = row.hands === survey.recommended;
      if (rec) tr.classList.add("recommended");
      tr.append(el("td", {}, row.hands), el("td", {}, row.stable), el("td", {}, row.unstable),
        el("td", {}, row.ratio === null || row.ratio === undefined ? "- (" + (row.reason || "no plan") + ")" : Number(row.ratio).toFixed(4)),
        el("td", {}, rec ? "recommended" : ""));
      return tr;
    }));
    const W = 520, H = 260, padL = 46, padB = 40, padT = 16, padR = 10;
    const root = chartFrame($("survey-chart"), W, H, "Ratio of stable states per hand configuration");
    const n = Math.max(rows.length, 1);
    const slot = (W - padL - padR) / n;
    const Y = (r) => H - padB - r * (H - padT - padB);
    for (const r of [0, 0.25, 0.5, 0.75, 1]) {
      root.append(svg("line", { x1: padL, x2: W - padR, y1: Y(r), y2: Y(r), class: "gridline" }));
      root.append(svg("text", { x: padL - 4, y: Y(r) + 4, "text-anchor": "end" }, r.toFixed(2)));
    }
    rows.forEach((row, i) => {
      const x = padL + i * slot + slot * 0.2;
      const ratio = typeof row.ratio === "number" ? row.ratio : 0;
      const rec = row.hands === survey.recommended;
      root.append(svg("rect", { x, y: Y(ratio), width: slot * 0.6, height: Y(0) - Y(ratio),
        class: "bar" + (rec ? " bar-recommended" : "") + (typeof row.ratio === "number" ? "" : " bar-none"), "data-hands": row.hands }));
      root.append(svg("text", { x: x + slot * 0.3, y: Y(ratio) - 4, "text-anchor": "middle" },
        typeof row.ratio === "number" ? row.ratio.toFixed(3) : "n/a"));
      root.append(svg("text", { x: x + slot * 0.3, y: H - padB + 16, "text-anchor": "middle" }, row.hands));
    });
    root.append(svg("text", { x: 12, y: H / 2, "text-anchor": "middle", transform: "rotate(-90 12 " + H / 2 + ")" }, "R = C / (C + U)"));
  }

  // ------------------------------------------------------------------ start
  function submitJob(e) {
    e.preventDefault();
    const kind = $("submit-kind").value;
    const request = { scenario: $("submit-scenario").value.trim() };
    const thr = $("submit-threshold").value;
    if (thr !== "") request.threshold_m = Number(thr) / 1000;
    const seed = $("submit-seed").value;
    if (seed !== "") request.seed = Number(seed);
    showProblem(null);
    api("POST", "/v1/jobs", { kind, request })
      .then((job) => { refreshJobs(); selectJob(job.id); })
      .catch((err) => { $("detail-empty").hidden = true; $("detail-body").hidden = false; showProblem(err); });
  }

  function init() {
    $("token-form").addEventListener("submit", (e) => { e.preventDefault(); setToken($("token").value); });
    $("token-clear").addEventListener("click", () => { stopLive(); setToken(""); });
    $("jobs-refresh").addEventListener("click", refreshJobs);
    $("submit-form").addEventListener("submit", submitJob);
    $("btn-audit").addEventListener("click", downloadAudit);
    for (const b of $("actions").querySelectorAll("button[data-action]")) {
      b.addEventListener("click", () => act(b.dataset.action));
    }
    if (state.token) $("token").placeholder = "token set (" + state.token.slice(0, 6) + "...)";
    refreshHealth();
    loadIdentity();
    refreshJobs();
    setInterval(refreshHealth, 5000);
    setInterval(() => {
      if (!state.token || document.visibilityState === "hidden") return;
      refreshJobs();
      if (state.me === undefined && !state.identityPending) loadIdentity();  // a refused or failed look-up is retried
    }, LIST_REFRESH_MS);
  }

  // exposed for tests and the browser console
  window.regraspConsole = { shrinkConvex, parseSse, refusal, state };
  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", init); else init();
})();
