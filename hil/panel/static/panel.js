// The rig panel's page: live charts (Plotly, served from the installed plotly package),
// operator actions, past runs. It only talks to its own server (token on every request).
"use strict";
const TOKEN = document.querySelector('meta[name="panel-token"]').content;
const MAX_POINTS = 20000;  // per trace: the page's memory stays bounded over any run
const DRAW_PERIOD = 50;    // ms between two redraws
const panel = {client: null, seq: 0, mine: false, lastMcuT: null, drawn: 0,
               latency: [], pending: null, clicks: []};
window.panel = panel;  // read by the tests and the benchmark
const $ = (id) => document.getElementById(id);
const mm = (m) => (m * 1e3).toFixed(3);
const esc = (s) => String(s).replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`);

function api(path, options = {}) {
  const headers = Object.assign({"X-Panel-Token": TOKEN}, options.headers || {});
  return fetch(path, Object.assign({}, options, {headers})).then(async (r) => {
    const body = await r.json().catch(() => ({error: r.statusText}));
    if (!r.ok) throw new Error(body.error || r.statusText);
    return body;
  });
}

function say(text, bad) { $("message").textContent = text; $("message").className = "message" + (bad ? " bad" : ""); }

const layout = (title, x, y) => ({title: {text: title, font: {size: 13}, x: 0.02}, margin: {l: 55, r: 10, t: 28, b: 38},
  xaxis: {title: {text: x}}, yaxis: {title: {text: y}}, showlegend: true,
  legend: {orientation: "h", y: 1.0, x: 1.0, xanchor: "right", yanchor: "bottom"}});
const line = (name) => ({x: [], y: [], mode: "lines", name, line: {width: 1}});
const config = {displaylogo: false, responsive: true};

function newCharts() {
  Plotly.newPlot("chart-force", [line("input force")], layout("Input force", "MCU time [s]", "F [N]"), config);
  Plotly.newPlot("chart-position", [line("crosshead x"), line("platen")], layout("Positions", "MCU time [s]", "[mm]"), config);
  Plotly.newPlot("chart-velocity", [line("crosshead velocity")], layout("Crosshead velocity", "MCU time [s]", "v [mm/s]"), config);
  Plotly.newPlot("chart-curve", [line("force curve")], layout("Input force against crosshead position", "x [mm]", "F [N]"), config);
  panel.drawn = 0;
}

function queue(batch) {
  const p = panel.pending || (panel.pending = {rx: [], t: [], x: [], platen: [], force: [], v: []});
  p.rx.push(...batch.rx); p.t.push(...batch.mcu_t); p.force.push(...batch.force);
  p.x.push(...batch.x.map((v) => v * 1e3)); p.platen.push(...batch.platen.map((v) => v * 1e3));
  p.v.push(...batch.v.map((v) => v * 1e3));
}

function draw() {
  const p = panel.pending;
  if (!p) return;
  panel.pending = null;
  const done = [
    Plotly.extendTraces("chart-force", {x: [p.t], y: [p.force]}, [0], MAX_POINTS),
    Plotly.extendTraces("chart-position", {x: [p.t, p.t], y: [p.x, p.platen]}, [0, 1], MAX_POINTS),
    Plotly.extendTraces("chart-velocity", {x: [p.t], y: [p.v]}, [0], MAX_POINTS),
    Plotly.extendTraces("chart-curve", {x: [p.x], y: [p.force]}, [0], MAX_POINTS)];
  Promise.all(done).then(() => {
    const now = Date.now() / 1000;  // the samples' host arrival is on the same clock
    for (const rx of p.rx) panel.latency.push(now - rx);
    if (panel.latency.length > 50000) panel.latency.splice(0, panel.latency.length - 50000);
    panel.drawn += p.t.length;
    panel.lastMcuT = p.t[p.t.length - 1];
    $("mcu-time").textContent = panel.lastMcuT.toFixed(3);
    $("force-now").textContent = p.force[p.force.length - 1].toFixed(2);
  });
}
setInterval(draw, DRAW_PERIOD);

function showStatus(s) {
  $("backend").textContent = s.backend === "rig" ? "rig (serial)" : "simulated rig (FMU)";
  $("state").textContent = s.busy ? `${s.state} (${s.busy})` : s.state;
  $("state").className = "pill " + s.state;
  $("faults").textContent = (s.faults || []).length ? "faults: " + s.faults.join(", ") : "no fault";
  $("homed").textContent = s.homed === null || s.homed === undefined ? "no home switch (simulated)"
    : (s.homed ? "homed" : "NOT homed") + (s.home_switch ? ", home switch active" : "");
  $("cycles-done").textContent = s.cycles ?? 0; $("cycles-total").textContent = s.cycles_total ?? 0;
  if (s.position) { $("x-now").textContent = mm(s.position.x); $("platen-now").textContent = mm(s.position.platen); }
  const l = s.limits;
  if (l) $("limits").textContent = `|F| <= ${l.force_limit_n} N, x in [${mm(l.travel_m[0])}, ${mm(l.travel_m[1])}] mm, `
    + `v <= ${(l.speed_max_m_s * 1e3).toFixed(0)} mm/s` + (l.mcu ? `; MCU |F| <= ${l.mcu.force_limit_n} N, heartbeat ${l.mcu.heartbeat_timeout_ms} ms` : "");
  const k = s.link || {};
  $("link").textContent = s.backend === "rig" && s.connected
    ? `lost ${k.lost_samples}, late ${k.late_attempts}, retransmitted ${k.retransmissions}, bad frames ${k.bad_frames}, gap p99 ${((k.arrival_gap_p99_s || 0) * 1e3).toFixed(1)} ms`
    : (s.backend === "rig" ? "not connected" : "none (simulated)");
  $("run-dir").textContent = s.run_dir || "-";
  if (s.message && !panel.sticky) say(s.message, false);
}

function connect() {
  const ws = new WebSocket(`ws://${location.host}/ws?token=${encodeURIComponent(TOKEN)}`);
  ws.onmessage = (ev) => {
    const m = JSON.parse(ev.data);
    if (m.type === "hello") { panel.client = m.client; panel.seq = 0; }
    else if (m.type === "status") showStatus(m);
    else if (m.type === "samples") queue(m);
    else if (m.type === "lease") {
      panel.mine = m.mine; $("lease").textContent = m.mine ? "commanding" : (m.taken ? "watching (another page commands)" : "watching");
      $("btn-lease").textContent = m.mine ? "Release command" : "Take command";
      if (!m.taken && !panel.askedOnce) { panel.askedOnce = true; lease(true); }
    } else if (m.type === "done") { panel.sticky = false; say(m.message, !m.ok); if (m.result) $("result").textContent = JSON.stringify(m.result, null, 1); if (m.action === "run") listRuns(); }
    else if (m.type === "notice") say(m.message, false);
  };
  ws.onclose = () => { say("connection to the panel lost; reconnecting", true); setTimeout(connect, 1000); };
}

function lease(take) {
  if (!panel.client) return;
  api("/api/lease", {method: "POST", headers: {"Content-Type": "application/json"},
    body: JSON.stringify({client: panel.client, take})}).catch((e) => say(e.message, true));
}

function act(action, args = {}, moves = false) {
  if (moves && !window.confirm(`${action}: this moves the rig. Go ahead?`)) return Promise.resolve();
  const t_click = Date.now() / 1000;
  panel.clicks.push({action, t: t_click});
  if (panel.clicks.length > 100) panel.clicks.shift();
  panel.seq += 1;
  const body = {action, args, client: panel.client, seq: panel.seq, t_click};
  if (moves) body.confirm = true;
  if (action === "run") newCharts();
  panel.sticky = true;
  return api("/api/action", {method: "POST", headers: {"Content-Type": "application/json"}, body: JSON.stringify(body)})
    .then(() => say(`${action}: sent`, false)).catch((e) => say(`${action}: ${e.message}`, true));
}

const num = (id) => Number($(id).value);
$("btn-stop").onclick = () => act("stop");
document.addEventListener("keydown", (e) => { if (e.key === "Escape") act("stop"); });
$("btn-estop").onclick = () => act("estop");
$("btn-home").onclick = () => act("home", {}, true);
$("btn-clear").onclick = () => act("clear");
$("btn-lease").onclick = () => lease(!panel.mine);
$("btn-jog").onclick = () => act("jog", {[$("jog-mode").value]: num("jog-mm") / 1e3, speed: num("jog-speed") / 1e3}, true);
$("btn-tare").onclick = () => act("tare", {samples: num("tare-n")});
$("btn-span").onclick = () => act("span", {known_force: num("span-n")});
$("btn-store").onclick = () => {
  const r = panel.calibration;
  if (!r || r.offset === undefined || r.gain === undefined) { say("tare and span first", true); return; }
  act("store", {offset: r.offset, gain: r.gain});
};
$("btn-check").onclick = () => act("check", {}, true);
$("btn-run").onclick = async () => {
  const job = $("job").value, args = {job, cycles: num("cycles")};
  if (job === "speed") args.speed = num("speed") / 1e3;
  if (job === "plan") {
    const file = $("plan-file").files[0];
    if (!file) { say("choose a plan CSV first", true); return; }
    try {
      const up = await api("/api/plan", {method: "POST", headers: {"Content-Type": "text/csv"}, body: await file.text()});
      args.plan = up.plan;
    } catch (e) { say(`plan: ${e.message}`, true); return; }
  }
  act("run", args, true);
};

// --- past runs -------------------------------------------------------------------------
const STAT_NAMES = {stroke_initial: "S_i", stroke_final: "S_f", stroke: "stroke S", stroke_error: "stroke error",
  force_forward_max: "F_F(max)", force_forward_rms: "F_F(rms)", force_backward_min: "F_B(min)",
  force_backward_rms: "F_B(rms)", force_toggle: "F_TP"};
function listRuns() {
  api("/api/runs").then((runs) => {
    $("runs").tBodies[0].innerHTML = runs.map((r) => `<tr><td><input type="checkbox" value="${esc(r.name)}"></td>`
      + `<td>${esc(r.name)}</td><td>${esc((r.job || "").slice(0, 40))}</td><td>${esc(r.cycles)}</td>`
      + `<td>${r.aborted ? "stopped" : (r.finished ? "complete" : "open")}</td></tr>`).join("");
  }).catch((e) => say(`runs: ${e.message}`, true));
}
function fmt(key, v) { if (v === null || v === undefined) return "-"; return key.startsWith("force") ? v.toFixed(2) + " N" : (v * 1e3).toFixed(3) + " mm"; }
async function openRuns() {
  const names = [...document.querySelectorAll("#runs input:checked")].map((c) => c.value).slice(0, 2);
  if (!names.length) { say("select one run, or two to overlay", true); return; }
  const runs = await Promise.all(names.map((n) => api(`/api/runs/${encodeURIComponent(n)}`)));
  Plotly.newPlot("chart-past", runs.map((r) => ({x: r.x.map((v) => v * 1e3), y: r.force, mode: "lines", name: r.name, line: {width: 1}})),
    layout(runs.length > 1 ? "Two runs overlaid: input force against crosshead position" : "Input force against crosshead position", "x [mm]", "F [N]"), config);
  const head = "<tr><th>statistic</th>" + runs.map((r) => `<th>${esc(r.name)}<br>mean (3 sigma)</th>`
    + `<th>prototype, same condition<br>mean (3 sigma)</th>`).join("") + "</tr>";
  const cell = (r, key, p) => (p ? `Table ${p.table}: ${fmt(key, p.mean)} (${fmt(key, p.three_sigma)})`
    : (r.statistics.some((x) => x.paper) ? "-" : "no cell (not a Tables 3-8 condition)"));
  const rows = runs[0].statistics.map((s, i) => `<tr><td>${STAT_NAMES[s.key] || s.key}</td>` + runs.map((r) => {
    const x = r.statistics[i];
    return `<td>${fmt(s.key, x.mean)} (${fmt(s.key, x.three_sigma)})</td><td>${cell(r, s.key, x.paper)}</td>`;
  }).join("") + "</tr>");
  $("stats").innerHTML = head + rows.join("");
}
$("btn-refresh").onclick = listRuns;
$("btn-open").onclick = () => openRuns().catch((e) => say(e.message, true));

newCharts();
listRuns();
connect();
