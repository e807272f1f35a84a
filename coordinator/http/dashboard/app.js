// The Prism farm dashboard: a static page over the coordinator's HTTP/JSON API (/api/v1/,
// docs/api/openapi.json). It polls the jobs and workers once a second; for the selected job it
// draws the tile map, reloads the preview when a tile was finalised, plots the job's error
// estimate against time (GET .../convergence), and shows the report once the job is done; each worker's
// throughput is its accepted samples over the last 10 s of polls. Cancel asks first.
// The API token is kept in this tab's sessionStorage only.
"use strict";

const state = { token: sessionStorage.getItem("prism-token") || "", selected: null,
                finalised: -1, previewUrl: null, workerSamples: new Map() };
const $ = (id) => document.getElementById(id);

async function api(path, options = {}) {
  const headers = Object.assign({}, options.headers || {});
  if (state.token) headers.Authorization = "Bearer " + state.token;
  const response = await fetch(path, Object.assign({}, options, { headers }));
  if (!response.ok) {
    let message = response.statusText;
    try { message = (await response.json()).message || message; } catch (e) { /* not JSON */ }
    const error = new Error(message);
    error.status = response.status;
    throw error;
  }
  return response;
}

const shortState = (s) => (s || "").replace("JOB_STATE_", "").toLowerCase();
const finished = (s) => ["done", "failed", "cancelled"].includes(shortState(s));

function eta(seconds) {
  if (seconds < 0) return "?";
  const s = Math.round(seconds);
  return s >= 3600 ? `${Math.floor(s / 3600)}h${String(Math.floor(s % 3600 / 60)).padStart(2, "0")}`
                   : `${Math.floor(s / 60)}:${String(s % 60).padStart(2, "0")}`;
}

function cell(row, text) {
  const td = row.insertCell();
  td.textContent = text;
  return td;
}

function renderJobs(jobs) {
  const body = $("jobs").tBodies[0];
  body.replaceChildren();
  for (const job of jobs) {
    const p = job.progress || {};
    const row = body.insertRow();
    row.dataset.job = job.jobId;
    if (job.jobId === state.selected) row.classList.add("selected");
    cell(row, job.jobId);
    cell(row, (job.spec && job.spec.name) || "");
    cell(row, shortState(job.state));
    const bar = document.createElement("progress");
    bar.max = Number(p.samplesTotal || 0) || 1;
    bar.value = Number(p.samplesDone || 0);
    const td = cell(row, "");
    td.append(bar, ` ${(100 * bar.value / bar.max).toFixed(1)} %`);
    cell(row, Math.round(p.samplesPerSecond || 0).toLocaleString());
    cell(row, finished(job.state) ? "" : eta(p.etaSeconds));
    const actions = cell(row, "");
    if (!finished(job.state)) {
      const button = document.createElement("button");
      button.textContent = "Cancel";
      button.className = "cancel";
      button.onclick = async (event) => {
        event.stopPropagation();
        if (!confirm(`Cancel job ${job.jobId}?`)) return;
        try {
          await api(`/api/v1/jobs/${job.jobId}:cancel`, { method: "POST" });
        } catch (e) {
          $("status").textContent = `cancel ${job.jobId}: ${e.message}`;
        }
        refresh();
      };
      actions.append(button);
    }
    row.onclick = () => select(job.jobId);
  }
}

function renderWorkers(workers) {
  const body = $("workers").tBodies[0];
  body.replaceChildren();
  const now = Date.now();
  for (const w of workers) {
    const row = body.insertRow();
    cell(row, w.workerId);
    cell(row, w.host);
    cell(row, w.state);
    cell(row, w.threads);
    cell(row, w.tasksCompleted);
    // Throughput: accepted samples between this poll and the one a few seconds before.
    const samples = Number(w.samplesCompleted || 0);
    const seen = (state.workerSamples.get(w.workerId) || []).filter((p) => now - p.t < 10000);
    seen.push({ t: now, samples });
    state.workerSamples.set(w.workerId, seen);
    const first = seen[0];
    const rate = now > first.t ? (samples - first.samples) / ((now - first.t) / 1000) : 0;
    cell(row, Math.round(rate).toLocaleString()).className = "rate";
    cell(row, `${((now - Number(w.lastHeartbeatUnixMs)) / 1000).toFixed(1)} s ago`);
    cell(row, w.currentTask || "");
  }
}

const tileColours = { q: "#ddd", l: "#e90", d: "#3a3", f: "#c22", c: "#789" };

function drawTiles(map) {
  const canvas = $("tiles");
  const ctx = canvas.getContext("2d");
  const scale = Math.min(canvas.width / map.width, canvas.height / map.height);
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const counts = { q: 0, l: 0, d: 0, f: 0, c: 0 };
  for (let i = 0; i < map.states.length; ++i) {
    const s = map.states[i];
    counts[s] = (counts[s] || 0) + 1;
    const x = (i % map.tilesX) * map.tileSize, y = Math.floor(i / map.tilesX) * map.tileSize;
    ctx.fillStyle = tileColours[s] || "#000";
    ctx.fillRect(x * scale, y * scale, Math.max(1, map.tileSize * scale - 1),
                 Math.max(1, map.tileSize * scale - 1));
  }
  $("tile-counts").textContent =
    `${counts.d} done, ${counts.l} leased, ${counts.q} queued, ${counts.f} failed` +
    (counts.c > 0 ? `, ${counts.c} cancelled` : "");
  canvas.dataset.states = map.states;
}

// The job's error estimate (relative standard error of the image mean, log scale) against time.
function drawConvergence(points) {
  const canvas = $("convergence");
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const usable = points.filter((p) => p.relativeError > 0);
  canvas.dataset.points = String(usable.length);
  if (usable.length === 0) return;
  canvas.dataset.last = String(usable[usable.length - 1].relativeError);
  const t1 = Math.max(usable[usable.length - 1].seconds, 1e-3);
  const logs = usable.map((p) => Math.log10(p.relativeError));
  const hi = Math.ceil(Math.max(...logs)), lo = Math.min(Math.floor(Math.min(...logs)), hi - 1);
  const left = 40, top = 10, w = canvas.width - 50, h = canvas.height - 40;
  ctx.strokeStyle = "#888";
  ctx.strokeRect(left, top, w, h);
  ctx.beginPath();
  ctx.strokeStyle = "#26c";
  usable.forEach((p, i) => {
    const x = left + w * p.seconds / t1;
    const y = top + h * (hi - Math.log10(p.relativeError)) / (hi - lo);
    i ? ctx.lineTo(x, y) : ctx.moveTo(x, y);
  });
  ctx.stroke();
  ctx.fillStyle = "#444";
  ctx.fillText(`1e${hi}`, 2, top + 8);
  ctx.fillText(`1e${lo}`, 2, top + h);
  ctx.fillText(`${t1.toFixed(1)} s`, canvas.width - 45, canvas.height - 12);
}

async function refreshPreview(jobId) {
  try {
    const response = await api(`/api/v1/jobs/${jobId}/preview.png`);
    const url = URL.createObjectURL(await response.blob());
    if (state.previewUrl) URL.revokeObjectURL(state.previewUrl);
    state.previewUrl = url;
    $("preview").src = url;
    $("preview").dataset.version = String(Number($("preview").dataset.version || 0) + 1);
  } catch (e) {
    if (e.status !== 412) $("status").textContent = `preview: ${e.message}`;
  }
}

async function refreshJob(job) {
  $("job").hidden = false;
  $("job-id").textContent = job.jobId;
  $("job-state").textContent = shortState(job.state);
  const map = await (await api(`/api/v1/jobs/${job.jobId}/tiles`)).json();
  drawTiles(map);
  const p = job.progress || {};
  drawConvergence((await (await api(`/api/v1/jobs/${job.jobId}/convergence`)).json()).points || []);
  if (p.tilesFinalised !== state.finalised) {
    state.finalised = p.tilesFinalised;
    await refreshPreview(job.jobId);
  }
  if (job.reportJson) {
    const report = JSON.parse(job.reportJson);
    const shown = {};
    for (const key of ["integrator", "samples_per_second", "render_seconds", "auto", "prepass",
                       "gradient", "filtered"])
      if (key in report) shown[key] = report[key];
    $("report").textContent = JSON.stringify(shown, null, 2);
  }
}

function select(jobId) {
  state.selected = jobId;
  state.finalised = -1;
  refresh();
}

async function refresh() {
  try {
    const jobs = (await (await api("/api/v1/jobs?limit=50")).json()).jobs || [];
    renderJobs(jobs);
    const workers = (await (await api("/api/v1/workers")).json()).workers || [];
    renderWorkers(workers);
    const job = jobs.find((j) => j.jobId === state.selected);
    if (job) await refreshJob(job);
    $("status").textContent = `updated ${new Date().toLocaleTimeString()}`;
  } catch (e) {
    $("status").textContent = e.status === 401 ? "enter the API token" : `error: ${e.message}`;
  }
}

$("token").value = state.token;
$("login").onsubmit = (event) => {
  event.preventDefault();
  state.token = $("token").value;
  sessionStorage.setItem("prism-token", state.token);
  refresh();
};
refresh();
setInterval(refresh, 1000);
