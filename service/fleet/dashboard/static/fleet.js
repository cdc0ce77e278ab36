// The fleet dashboard: reads the shore's REST API (same origin, bearer token typed by the user)
// and draws with plotly, in the vessel dashboard's style (service/dashboard/static/app.js).
// Every text from the service goes through textContent, never innerHTML.
"use strict";

const POLL_MS = 15000;
const TOKEN_KEY = "recal-fleet-token";
const COLORS = { ok: "#3ecf8e", bad: "#ff6b6b", accent: "#5fb3ff", held: "#b48cff", muted: "#93a4b8", warn: "#f5b942" };
const PLOT_LAYOUT = {
  paper_bgcolor: "rgba(0,0,0,0)", plot_bgcolor: "#101a24",
  font: { color: "#e3e9f0", size: 13, family: "DejaVu Sans, sans-serif" },
  margin: { l: 70, r: 20, t: 10, b: 55 }, showlegend: true,
  legend: { orientation: "h", y: -0.22, font: { size: 12 } },
  xaxis: { gridcolor: "#263445", zerolinecolor: "#3a4d63" },
  yaxis: { gridcolor: "#263445", zerolinecolor: "#3a4d63" },
};
const PLOT_CONFIG = { displaylogo: false, responsive: true,
  modeBarButtonsToRemove: ["select2d", "lasso2d", "toImage"] };
const state = { overview: null, sort: { key: "attention", up: true }, unit: null, versions: [] };

// ---- small helpers (as app.js) -----------------------------------------------------------------
function el(tag, props, ...children) {
  const node = document.createElement(tag);
  Object.assign(node, props || {});
  for (const c of children) node.append(c instanceof Node ? c : String(c ?? ""));
  return node;
}
const $ = (id) => document.getElementById(id);
const isNum = (v) => typeof v === "number" && Number.isFinite(v);
function fmt(v, digits) { return isNum(v) ? v.toFixed(digits) : "-"; }
function layout(extra) {
  const out = structuredClone(PLOT_LAYOUT);
  for (const [k, v] of Object.entries(extra)) {
    out[k] = (typeof v === "object" && v && !Array.isArray(v) && out[k]) ? { ...out[k], ...v } : v;
  }
  return out;
}
function token() { return sessionStorage.getItem(TOKEN_KEY) || ""; }
async function getJSON(path) {
  const headers = { Accept: "application/json" };
  if (token()) headers.Authorization = `Bearer ${token()}`;
  const r = await fetch(path, { headers });
  if (!r.ok) {
    const body = await r.json().catch(() => ({}));
    const e = new Error(`${path}: ${r.status} ${body.detail || r.statusText}`); e.status = r.status; throw e;
  }
  return r.json();
}
function when(iso) { return iso ? iso.replace("T", " ").slice(0, 16) + " UTC" : "-"; }
function bytesWord(n) {
  if (!isNum(n)) return "-";
  return n >= 1048576 ? `${(n / 1048576).toFixed(1)} MiB` : n >= 1024 ? `${(n / 1024).toFixed(1)} KiB` : `${Math.round(n)} B`;
}

// ---- coefficients (the vessel page's flat names and display units) ----------------------------
const KEYS = {
  scale: { prefix: "K", unit: (s) => (s === "gyro" ? "ppm of nominal" : "ppm"), ppm: true },
  bias: { prefix: "b", unit: (s) => (s === "gyro" ? "deg/h" : "µg"), factor: (s) => (s === "gyro" ? 1 : 1e6) },
};
const val = (x, s) => (typeof x === "function" ? x(s) : x);
function flatten(doc) {
  const out = [];
  const coeffs = (doc && doc.coefficients) || {};
  for (const sensor of ["gyro", "accel"]) {
    for (const key of Object.keys(KEYS)) {
      const v = coeffs[sensor]?.[key];
      if (!Array.isArray(v)) continue;
      const sig = doc.uncertainty?.[sensor]?.[key];
      ["x", "y", "z"].forEach((a, i) => out.push({ id: `${sensor}.${key}.${KEYS[key].prefix}${a}`, sensor, key,
        label: `${sensor} ${KEYS[key].prefix}${a}`, value: v[i], sigma: Array.isArray(sig) ? sig[i] : null }));
    }
  }
  return out;
}

// ---- the overview ------------------------------------------------------------------------------
const FLAG_ORDER = ["rejected", "drift", "outlier", "conflicts", "stale", "never"];
const COLUMNS = [
  { key: "unit", head: "Unit", get: (u) => u.unit },
  { key: "attention", head: "Attention", get: (u) => attentionRank(u), cell: (u) => el("td", {}, ...u.attention.map((a) => el("span", { className: `flag flag-${a}` }, a))) },
  { key: "model", head: "Model", get: (u) => u.model || "" },
  { key: "current_version", head: "Current", num: true, get: (u) => u.current_version ?? -1, show: (u) => (u.current_version == null ? "-" : `v${u.current_version}`) },
  { key: "age_days", head: "Age (d)", num: true, get: (u) => u.age_days ?? -1, show: (u) => fmt(u.age_days, 1) },
  { key: "versions", head: "Versions", num: true, get: (u) => u.versions },
  { key: "rejected", head: "Rejected", num: true, get: (u) => u.rejected.count },
  { key: "last_reasons", head: "Last rejection", get: (u) => u.rejected.last_reasons.join("; "), cell: (u) => el("td", { className: "reasons-cell", title: u.rejected.last_reasons.join("\n") }, u.rejected.last_version == null ? "-" : `v${u.rejected.last_version}: ${u.rejected.last_reasons.join("; ") || "no reasons"}`) },
  { key: "last_trigger", head: "Last trigger", get: (u) => u.last_trigger || "" },
  { key: "drift", head: "Drift", get: (u) => u.drift.state, cell: (u) => el("td", { className: `state-${u.drift.state}`, title: u.drift.suspect || "" }, u.drift.state + (isNum(u.drift.statistic) ? ` (${u.drift.statistic.toFixed(1)}/${fmt(u.drift.threshold, 1)})` : "")) },
  { key: "heading", head: "Heading err (°)", num: true, get: (u) => u.heading_error_deg_rms ?? -1, show: (u) => (isNum(u.heading_error_deg_rms) ? u.heading_error_deg_rms.toPrecision(2) : "-") },
  { key: "contact", head: "Last contact", get: (u) => u.link.last_contact || "", cell: (u) => el("td", { className: `when state-${u.link.state}` }, when(u.link.last_contact)) },
  { key: "bytes", head: "Bytes/day (7 d)", num: true, get: (u) => u.link.bytes_7d, show: (u) => bytesWord(u.link.bytes_7d / 7) },
  { key: "conflicts", head: "Conflicts", num: true, get: (u) => u.conflicts ?? 0, cell: (u) => el("td", { className: `num${u.conflicts ? " state-drift" : ""}`, title: "rows received whose key was stored with other content (kept, see the unit)" }, String(u.conflicts ?? 0)) },
  { key: "backlog", head: "Backlog", num: true, get: (u) => u.link.backlog ?? -1, show: (u) => (u.link.backlog == null ? "-" : String(u.link.backlog)) },
  { key: "outlier", head: "Outlier", get: (u) => (u.outlier.flagged ? u.outlier.statistic : -1), cell: (u) => el("td", { className: u.outlier.flagged ? "state-drift" : "" }, u.outlier.flagged ? `χ² ${fmt(u.outlier.statistic, 1)} / ${u.outlier.dof}` : "no") },
];
function attentionRank(u) {
  const ranks = u.attention.map((a) => FLAG_ORDER.indexOf(a)).sort();
  return ranks.length ? ranks[0] * 10 - ranks.length : 99;
}

function renderTotals() {
  const o = state.overview, t = o.totals;
  const items = [["units", t.units], ["need attention", t.attention], ["versions", t.versions], ["rejected", t.rejected],
    ["drift", t.drift], ["outliers", t.outliers], ["link not up", t.stale], ["conflicts", t.conflicts ?? 0], ["windows", t.windows],
    ["traffic / day (7 d)", bytesWord(t.bytes_7d / 7)], ["backlog (rows)", t.backlog]];
  $("totals").replaceChildren(...items.map(([k, v]) => el("div", {}, el("dt", {}, k), el("dd", {}, String(v)))));
  $("generated").textContent = `as of ${when(o.generated_at)}`;
  const models = Object.entries(o.models || {}).map(([m, p]) => `${m}: fleet prior v${p.prior_version} (${p.outliers} outlier${p.outliers === 1 ? "" : "s"}${p.prior_stale ? "; being recomputed" : ""})`);
  $("models").textContent = models.length ? models.join(" · ") : "No fleet prior yet (a model needs a unit with two accepted versions).";
}

function renderUnits() {
  const { key, up } = state.sort;
  const col = COLUMNS.find((c) => c.key === key) || COLUMNS[1];
  const rows = state.overview.units.slice().sort((a, b) => {
    const x = col.get(a), y = col.get(b);
    const c = x < y ? -1 : x > y ? 1 : a.unit < b.unit ? -1 : 1;
    return up ? c : -c;
  });
  const table = $("units");
  table.tHead.replaceChildren(el("tr", {}, ...COLUMNS.map((c) => {
    const th = el("th", { className: `${c.num ? "num" : ""} ${c.key === key ? "sorted" : ""} ${c.key === key && !up ? "up" : ""}`.trim() }, c.head);
    th.dataset.key = c.key;
    th.addEventListener("click", () => { state.sort = { key: c.key, up: state.sort.key === c.key ? !state.sort.up : true }; renderUnits(); });
    return th;
  })));
  table.tBodies[0].replaceChildren(...rows.map((u) => {
    const tr = el("tr", { className: u.unit === state.unit ? "selected" : "" }, ...COLUMNS.map((c) =>
      (c.cell ? c.cell(u) : el("td", { className: c.num ? "num" : "" }, c.show ? c.show(u) : String(c.get(u))))));
    tr.dataset.unit = u.unit;
    tr.addEventListener("click", () => openUnit(u.unit));
    return tr;
  }));
}

async function loadOverview() {
  const pill = $("status");
  try {
    state.overview = await getJSON("overview");
    pill.className = "pill pill-ok"; pill.textContent = `${state.overview.totals.units} units`;
    $("problems").hidden = true;
    renderTotals();
    renderUnits();
  } catch (e) {
    pill.className = "pill pill-bad";
    pill.textContent = e.status === 401 ? "token needed" : "shore ?";
    $("problems").hidden = false;
    $("problems").textContent = e.status === 401 ? "Type the fleet administrator's token (or a unit's) above: every read of the shore needs one." : `cannot load: ${e.message}`;
  }
}

// ---- one unit ----------------------------------------------------------------------------------
async function openUnit(serial) {
  state.unit = serial;
  renderUnits();
  for (const id of ["unit-card", "link-card", "events-card"]) $(id).hidden = false;
  $("unit-name").textContent = serial;
  const row = state.overview.units.find((u) => u.unit === serial);
  $("unit-meta").textContent = row ? `${row.model || "no model"} · current ${row.current_version == null ? "none" : `v${row.current_version}`} (${fmt(row.age_days, 1)} days old) · ${row.versions} versions, ${row.rejected.count} rejected · drift ${row.drift.state} · link ${row.link.state}${row.conflicts ? ` · ${row.conflicts} conflict${row.conflicts === 1 ? "" : "s"}` : ""}${row.instance ? ` · database ${row.instance.slice(0, 8)}` : ""}` : "";
  $("unit-reasons").replaceChildren(...(row?.rejected.last_reasons || []).map((r) => el("li", {}, `v${row.rejected.last_version} rejected: ${r}`)));
  const path = `units/${encodeURIComponent(serial)}`;
  try {
    const [versions, detail, events] = await Promise.all([getJSON(`${path}/versions`), getJSON(path), getJSON(`${path}/events?limit=1000`)]);
    if (state.unit !== serial) return;
    state.versions = versions;
    fillCoefSelect();
    renderUnitChart();
    renderLink(detail);
    renderConflicts(detail);
    renderEvents(events.slice(-50).reverse());
  } catch (e) {
    $("unit-detail").textContent = `cannot load ${serial}: ${e.message}`;
  }
}

function fillCoefSelect() {
  const sel = $("unit-coef");
  const last = state.versions[state.versions.length - 1];
  const rows = flatten(last?.document?.document);
  const keep = sel.value;
  sel.replaceChildren(...rows.map((r) => el("option", { value: r.id }, `${r.label} (${val(KEYS[r.key].unit, r.sensor)})`)));
  sel.value = rows.some((r) => r.id === keep) ? keep : rows[0]?.id || "";
}

function renderUnitChart() {
  const id = $("unit-coef").value;
  const pts = state.versions.map((v) => {
    const row = flatten(v.document?.document).find((r) => r.id === id);
    if (!row || !isNum(row.value)) return null;
    // scale: ppm from the unit's first accepted value; bias: in its display unit
    return { v, row };
  }).filter(Boolean);
  const first = pts.find((p) => p.v.accepted) || pts[0];
  const key = first?.row.key;
  const show = (p) => (key === "scale" ? (p.row.value / first.row.value - 1) * 1e6 : p.row.value * val(KEYS.bias.factor, p.row.sensor));
  const sig = (p) => (!isNum(p.row.sigma) ? 0 : key === "scale" ? p.row.sigma / Math.abs(first.row.value) * 1e6 : p.row.sigma * val(KEYS.bias.factor, p.row.sensor));
  const acc = pts.filter((p) => p.v.accepted), rej = pts.filter((p) => !p.v.accepted);
  const hover = (p) => `v${p.v.version} ${p.v.accepted ? "accepted" : "REJECTED"} (${p.v.trigger || "-"})<br>${(p.v.document?.reasons || []).slice(0, 4).join("<br>") || "no reasons"}`;
  const traces = [
    { x: acc.map((p) => p.v.created_at), y: acc.map(show), mode: "lines+markers", name: "accepted",
      line: { color: COLORS.accent, width: 2 }, marker: { color: COLORS.ok, size: 10 },
      error_y: { type: "data", array: acc.map(sig), color: COLORS.ok, thickness: 1.2, width: 4 },
      text: acc.map(hover), hovertemplate: "%{text}<extra></extra>", customdata: acc.map((p) => p.v.version) },
    { x: rej.map((p) => p.v.created_at), y: rej.map(show), mode: "markers", name: "rejected",
      marker: { color: COLORS.bad, size: 13, symbol: "x-thin", line: { width: 3, color: COLORS.bad } },
      error_y: { type: "data", array: rej.map(sig), color: COLORS.bad, thickness: 1, width: 4 },
      text: rej.map(hover), hovertemplate: "%{text}<extra></extra>", customdata: rej.map((p) => p.v.version) },
  ];
  const label = first ? `${first.row.label} (${key === "scale" ? `ppm from v${first.v.version}` : val(KEYS.bias.unit, first.row.sensor)})` : id;
  const chart = $("unit-chart");
  Plotly.react(chart, traces, layout({ xaxis: { title: { text: "time (UTC)" }, type: "date" }, yaxis: { title: { text: label } } }), PLOT_CONFIG);
  chart.dataset.points = String(pts.length);
  if (!chart.dataset.clickBound) {
    chart.dataset.clickBound = "1";
    chart.on("plotly_click", (ev) => {
      const v = state.versions.find((r) => r.version === ev.points[0]?.customdata);
      if (v) $("unit-detail").textContent = `v${v.version} (${v.accepted ? "accepted" : "rejected"}, ${v.trigger}): ${(v.document?.reasons || []).join("; ") || "no reasons given"}`;
    });
  }
}

function renderConflicts(detail) {
  // rows received whose key (kind, database instance, id) was stored with other content: kept whole on shore
  $("unit-conflicts").replaceChildren(...(detail.conflict_rows || []).map((c) => el("li", {},
    `conflict: ${c.kind} ${c.id} of database ${c.instance ? c.instance.slice(0, 8) : "(legacy)"} received ${when(c.received_at)} differs from the row stored (digest ${c.digest.slice(0, 12)} vs ${c.stored_digest.slice(0, 12)})`)));
}

function renderLink(detail) {
  const days = detail.link || [];
  $("link-meta").textContent = `last contact ${when(detail.last_contact)} · rows stored ${Object.entries(detail.rows || {}).map(([k, n]) => `${k} ${n}`).join(", ")}`;
  Plotly.react($("link-chart"), [
    { x: days.map((d) => d.day), y: days.map((d) => d.compressed_bytes / 1024), type: "bar", name: "KiB received (gzip)", marker: { color: COLORS.accent } },
    { x: days.map((d) => d.day), y: days.map((d) => d.stored), type: "scatter", mode: "lines+markers", name: "rows stored", yaxis: "y2", line: { color: COLORS.ok } },
  ], layout({ xaxis: { type: "category" }, yaxis: { title: { text: "KiB per day" } },
    yaxis2: { title: { text: "rows" }, overlaying: "y", side: "right", gridcolor: "rgba(0,0,0,0)" }, margin: { l: 70, r: 60, t: 10, b: 55 } }), PLOT_CONFIG);
}

function renderEvents(events) {
  $("events").tBodies[0].replaceChildren(...events.map((e) => el("tr", {},
    el("td", { className: "when" }, when(e.at)), el("td", { className: "kind" }, e.kind),
    el("td", {}, e.data?.message || ""))));
}

// ---- start -------------------------------------------------------------------------------------
function start() {
  $("token").value = token();
  $("token-form").addEventListener("submit", (ev) => {
    ev.preventDefault();
    const t = $("token").value.trim();
    if (t) sessionStorage.setItem(TOKEN_KEY, t); else sessionStorage.removeItem(TOKEN_KEY);
    loadOverview();
  });
  $("unit-coef").addEventListener("change", renderUnitChart);
  loadOverview();
  setInterval(() => { if (token()) loadOverview(); }, POLL_MS);
}
document.addEventListener("DOMContentLoaded", start);
