// The operator's dashboard: reads the service's own API (same origin) and draws with plotly.
// Every text from the service goes through textContent, never innerHTML.
"use strict";

const POLL_MS = 4000;
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
const state = { current: null, previous: null, history: [], coverage: null, newest: null };

// ---- small helpers ---------------------------------------------------------------------------
function el(tag, props, ...children) {
  const node = document.createElement(tag);
  Object.assign(node, props || {});
  for (const c of children) node.append(c instanceof Node ? c : String(c ?? ""));
  return node;
}
const $ = (id) => document.getElementById(id);
const isNum = (v) => typeof v === "number" && Number.isFinite(v);
function fmt(v, digits) { return isNum(v) ? v.toFixed(digits) : "-"; }

async function getJSON(path) {
  const r = await fetch(path, { headers: { Accept: "application/json" } });
  if (!r.ok) { const e = new Error(`${path}: ${r.status}`); e.status = r.status; throw e; }
  return r.json();
}

function layout(extra) {
  const out = structuredClone(PLOT_LAYOUT);
  for (const [k, v] of Object.entries(extra)) {
    out[k] = (typeof v === "object" && v && !Array.isArray(v) && out[k]) ? { ...out[k], ...v } : v;
  }
  return out;
}

// ---- coefficients: names, units, display scaling ---------------------------------------------
// [sensor, key, display unit, factor from stored units, digits]
const KEYS = {
  scale: { prefix: "K", unit: (s) => (s === "gyro" ? "per deg/h" : "per g"), factor: 1, digits: 7, sigmaPpm: true },
  bias: { prefix: "b", unit: (s) => (s === "gyro" ? "deg/h" : "µg"), factor: (s) => (s === "gyro" ? 1 : 1e6), digits: (s) => (s === "gyro" ? 4 : 1) },
  misalignment: { prefix: "", unit: () => "µrad", factor: 1e6, digits: 1 },
  quadratic: { prefix: "K2", unit: () => "µg/g²", factor: 1e6, digits: 1 },
};
const val = (x, s) => (typeof x === "function" ? x(s) : x);

/** Flat list of {id, sensor, key, label, value, sigma, status} from a stored document. */
function flatten(doc) {
  const out = [];
  const coeffs = (doc && doc.coefficients) || {};
  for (const sensor of ["gyro", "accel"]) {
    const block = coeffs[sensor];
    if (!block) continue;
    for (const key of Object.keys(KEYS)) {
      const v = block[key];
      if (v === undefined || v === null) continue;
      const sig = doc.uncertainty?.[sensor]?.[key];
      const st = doc.status?.[sensor]?.[key];
      const names = Array.isArray(v) ? ["x", "y", "z"].map((a) => KEYS[key].prefix + a) : Object.keys(v);
      names.forEach((name, i) => {
        const pick = (o) => (o == null ? undefined : Array.isArray(o) ? o[i] : o[name]);
        out.push({ id: `${sensor}.${key}.${name}`, sensor, key, label: `${sensor} ${name}`,
          value: pick(v), sigma: pick(sig), status: pick(st) });
      });
    }
  }
  return out;
}
function display(row, x) {
  const k = KEYS[row.key];
  return isNum(x) ? x * val(k.factor, row.sensor) : null;
}
function showValue(row) { return fmt(display(row, row.value), val(KEYS[row.key].digits, row.sensor)); }
function showSigma(row) {
  if (KEYS[row.key].sigmaPpm) return isNum(row.sigma) && isNum(row.value) ? `${fmt(row.sigma / Math.abs(row.value) * 1e6, 2)} ppm` : "-";
  return fmt(display(row, row.sigma), val(KEYS[row.key].digits, row.sensor) + 1);
}

// ---- current version ---------------------------------------------------------------------------
function renderCurrent() {
  const rec = state.current;
  const box = $("coefficients");
  box.replaceChildren();
  if (!rec) {
    $("version").textContent = "none yet";
    $("verdict").textContent = "";
    $("version-meta").textContent = "No calibration has been accepted yet.";
    return;
  }
  $("version").textContent = `v${rec.version}`;
  const verdict = $("verdict");
  verdict.textContent = rec.accepted ? "ACCEPTED" : "REJECTED";
  verdict.className = `verdict ${rec.accepted ? "accepted" : "rejected"}`;
  const doc = rec.document || {};
  const when = new Date(rec.created_at).toISOString().replace("T", " ").slice(0, 19) + " UTC";
  const chi = isNum(doc.chi2_red) ? `, χ²ᵣ ${doc.chi2_red.toFixed(2)}` : "";
  const obs = doc.observability?.verdict ? `, observability ${doc.observability.verdict}` : "";
  $("version-meta").textContent = `${when} · ${rec.trigger} trigger · ${rec.method} · ${rec.positions_used.length} windows${chi}${obs}`
    + (rec.prior_version ? ` · previous v${rec.prior_version}` : "");
  $("reasons").replaceChildren(...(rec.reasons || []).map((r) => el("li", {}, r)));
  renderNavImpact(doc.navigation_impact, rec.reasons || [], doc.navigation);
  const prev = state.previous ? new Map(flatten(state.previous.document).map((r) => [r.id, r])) : new Map();
  const changeHead = state.previous ? `Δ vs v${state.previous.version} (σ)` : "Δ (σ)";
  const rows = flatten(doc);
  for (const sensor of ["gyro", "accel"]) {
    const mine = rows.filter((r) => r.sensor === sensor);
    if (!mine.length) continue;
    const head = el("tr", {}, ...["Coefficient", "Value", "1σ", "Unit", changeHead, "Status"].map(
      (h, i) => el("th", { className: [1, 2, 4].includes(i) ? "num" : "" }, h)));
    const body = el("tbody");
    let group = null;
    for (const row of mine) {
      if (row.key !== group) {
        group = row.key;
        body.append(el("tr", { className: "group" }, el("td", { colSpan: 6 }, `${sensor === "gyro" ? "Gyro" : "Accelerometer"} ${row.key}`)));
      }
      body.append(coefficientRow(row, prev.get(row.id)));
    }
    box.append(el("div", { className: "table-wrap" }, el("table", { className: "coef" }, el("thead", {}, head), body)));
  }
}

function coefficientRow(row, p) {
  let change = "-", cls = "num";
  if (p && isNum(p.value) && isNum(row.value)) {
    const s = Math.hypot(row.sigma || 0, p.sigma || 0);
    if (s > 0) {
      const z = (row.value - p.value) / s;
      change = (z >= 0 ? "+" : "") + z.toFixed(2);
      cls += Math.abs(z) > 6 ? " change-huge" : Math.abs(z) > 3 ? " change-big" : "";
    }
  }
  return el("tr", {},
    el("td", {}, row.label), el("td", { className: "num" }, showValue(row)),
    el("td", { className: "num" }, showSigma(row)), el("td", {}, val(KEYS[row.key].unit, row.sensor)),
    el("td", { className: cls }, change),
    el("td", { className: `status-${row.status}` }, row.status || "-"));
}

function renderNavImpact(impact, reasons, nav) {
  const box = $("nav-impact");
  const figure = (value, label) => el("div", { className: "figure" }, el("b", {}, value), el("span", {}, label));
  const parts = [el("h2", {}, "Navigation impact"), ...headingFigures(nav, figure)];
  if (!impact || typeof impact !== "object") { box.replaceChildren(...parts); box.hidden = parts.length < 2; return; }
  const nmi = impact.static_24h_error_nmi_1sigma, m = impact.static_24h_error_m_1sigma;
  if (isNum(nmi)) parts.push(figure(`${nmi.toFixed(2)} nmi`, "24 h static position error, 1σ"));
  if (isNum(m)) parts.push(figure(`${Math.round(m)} m`, "same, in metres"));
  if (isNum(impact.latitude_deg)) parts.push(figure(`${impact.latitude_deg.toFixed(1)}°`, "latitude"));
  const ch = impact.change;
  if (ch && typeof ch === "object" && isNum(ch.old_error_nmi)) {
    const from = isNum(ch.from_version) ? `v${ch.from_version}` : "the previous version";
    parts.push(figure(`${ch.old_error_nmi.toFixed(2)} nmi`, `what ${from} leaves if this version is right`));
    if (isNum(ch.accepted_error_nmi_1sigma)) {
      parts.push(figure(`${ch.accepted_error_nmi_1sigma.toFixed(2)} nmi`, `${from}'s own 1σ`));
    }
  } else if (nav && typeof nav === "object" && isNum(nav.before?.position_error_nmi_1sigma)) {
    parts.push(figure(`${nav.before.position_error_nmi_1sigma.toFixed(2)} nmi`, `position error before (${nav.before.from})`));
  }
  // the gate's notes already carry the sentence once there is a previous version
  if (typeof impact.summary === "string" && !reasons.includes(impact.summary)) parts.push(el("p", { className: "impact-summary" }, impact.summary));
  box.replaceChildren(...parts);
  box.hidden = parts.length < 2;
}

// The gyrocompass heading error the horizontal gyro biases leave (document.navigation, written by
// service.recalibration.navigation_summary): this version's, and before it (the previous
// version's, or the prior's for the first one).
function headingFigures(nav, figure) {
  if (!nav || typeof nav !== "object") return [];
  const deg = (v) => `${v >= 1 ? v.toFixed(2) : v.toPrecision(2)}°`;
  const after = nav.after || {}, before = nav.before || {};
  if (!isNum(after.heading_error_deg_rms)) {
    return typeof nav.heading_error_unavailable === "string"
      ? [figure("-", `heading error: ${nav.heading_error_unavailable}`)] : [];
  }
  const out = [figure(deg(after.heading_error_deg_rms), "gyrocompass heading error, 1σ RMS over headings")];
  if (isNum(after.heading_error_deg_worst)) out.push(figure(deg(after.heading_error_deg_worst), "same, at the worst heading"));
  if (isNum(before.heading_error_deg_rms)) {
    const from = typeof before.from === "string" ? before.from : "before";
    out.push(figure(deg(before.heading_error_deg_rms), `heading error before (${from})`));
  }
  return out;
}

// ---- history -----------------------------------------------------------------------------------
function fillHistorySelect() {
  const sel = $("history-coef");
  const rows = flatten(state.current?.document || state.history[0]?.document);
  const keep = sel.value;
  if (sel.options.length === rows.length) return;
  sel.replaceChildren(...rows.map((r) => el("option", { value: r.id }, `${r.label} (${val(KEYS[r.key].unit, r.sensor)})`)));
  sel.value = rows.some((r) => r.id === keep) ? keep : rows[0]?.id || "";
}

function renderHistory() {
  fillHistorySelect();
  const id = $("history-coef").value;
  const pts = state.history.slice().reverse().map((rec) => {
    const row = flatten(rec.document).find((r) => r.id === id);
    return row ? { rec, y: display(row, row.value), s: display(row, row.sigma) } : null;
  }).filter((p) => p && isNum(p.y));
  const acc = pts.filter((p) => p.rec.accepted), rej = pts.filter((p) => !p.rec.accepted);
  const x = (ps) => ps.map((p) => p.rec.created_at);
  const hover = (p) => `v${p.rec.version} ${p.rec.accepted ? "accepted" : "REJECTED"}<br>${(p.rec.reasons || []).join("<br>") || "no reasons"}`;
  const sig = (p) => (isNum(p.s) ? p.s : 0);
  const traces = [
    { x: x(acc), y: acc.map((p) => p.y + sig(p)), mode: "lines", line: { width: 0 }, hoverinfo: "skip", showlegend: false },
    { x: x(acc), y: acc.map((p) => p.y - sig(p)), mode: "lines", line: { width: 0 }, fill: "tonexty",
      fillcolor: "rgba(95,179,255,0.18)", name: "±1σ (accepted)", hoverinfo: "skip" },
    { x: x(acc), y: acc.map((p) => p.y), mode: "lines+markers", name: "accepted",
      line: { color: COLORS.accent, width: 2 }, marker: { color: COLORS.ok, size: 10, symbol: "circle" },
      error_y: { type: "data", array: acc.map(sig), color: COLORS.ok, thickness: 1.2, width: 4 },
      text: acc.map(hover), hovertemplate: "%{text}<extra></extra>", customdata: acc.map((p) => p.rec.version) },
    { x: x(rej), y: rej.map((p) => p.y), mode: "markers", name: "rejected",
      marker: { color: COLORS.bad, size: 13, symbol: "x-thin", line: { width: 3, color: COLORS.bad } },
      error_y: { type: "data", array: rej.map(sig), color: COLORS.bad, thickness: 1, width: 4 },
      text: rej.map(hover), hovertemplate: "%{text}<extra></extra>", customdata: rej.map((p) => p.rec.version) },
  ];
  const row = flatten(state.current?.document).find((r) => r.id === id);
  const unit = row ? val(KEYS[row.key].unit, row.sensor) : "";
  const chart = $("history-chart");
  Plotly.react(chart, traces, layout({ xaxis: { title: { text: "time (UTC)" }, type: "date" },
    yaxis: { title: { text: `${row ? row.label : id} (${unit})` }, tickformat: row?.key === "scale" ? ".6f" : "" } }), PLOT_CONFIG);
  if (!chart.dataset.clickBound) {
    chart.dataset.clickBound = "1";
    chart.on("plotly_click", (ev) => {
      const v = ev.points[0]?.customdata;
      const rec = state.history.find((r) => r.version === v);
      if (!rec) return;
      $("history-detail").textContent = `v${rec.version} (${rec.accepted ? "accepted" : "rejected"}, ${rec.trigger}): ${(rec.reasons || []).join("; ") || "no reasons given"}`;
    });
  }
}

// ---- positions: coverage, advice, residuals, windows -------------------------------------------
const CANDIDATES = { "x down": [0, 0], "x up": [180, 0], "y down": [90, 0], "y up": [-90, 0], "z down": [0, 90], "z up": [0, -90] };

function renderCoverage() {
  const cov = state.coverage;
  if (!cov) return;
  const used = new Set(state.current?.positions_used || []);
  const ws = cov.windows.filter((w) => isNum(w.azimuth_deg));
  $("coverage-count").textContent = `${cov.windows.length} windows stored`;
  const suggested = new Set((cov.advice?.suggestions || []).map((s) => s.orientation));
  const names = Object.keys(CANDIDATES);
  const traces = [
    { x: ws.map((w) => w.azimuth_deg), y: ws.map((w) => w.elevation_deg), mode: "markers", name: "stored window",
      marker: { size: 12, color: ws.map((w) => w.temperature_c ?? 0), colorscale: "Portland", showscale: true,
        colorbar: { title: { text: "°C" }, thickness: 12, len: 0.8 },
        line: { width: ws.map((w) => (used.has(w.id) ? 2 : 0)), color: "#ffffff" } },
      text: ws.map((w) => `window ${w.id}${used.has(w.id) ? " (in the current fit)" : ""}<br>${fmt(w.temperature_c, 1)} °C`),
      hovertemplate: "%{text}<br>az %{x:.0f}°, el %{y:.0f}°<extra></extra>" },
    { x: names.map((n) => CANDIDATES[n][0]), y: names.map((n) => CANDIDATES[n][1]), mode: "markers+text",
      name: "axis down / up", text: names, textposition: "top center", textfont: { color: COLORS.muted, size: 11 },
      marker: { size: 16, symbol: "diamond-open", line: { width: 2 },
        color: names.map((n) => (suggested.has(n) ? COLORS.warn : COLORS.muted)) },
      hovertemplate: "%{text}<extra></extra>" },
  ];
  Plotly.react($("coverage-chart"), traces, layout({
    xaxis: { title: { text: "gravity azimuth in body x-y (deg, +x → +y)" }, range: [-190, 190], dtick: 45 },
    yaxis: { title: { text: "gravity elevation to +z (deg)" }, range: [-100, 100], dtick: 30 },
  }), PLOT_CONFIG);
  renderAdvice(cov.advice);
}

function renderAdvice(advice) {
  const box = $("advice");
  if (!advice) { box.replaceChildren(el("p", { className: "meta" }, "No accepted version yet: nothing to advise.")); return; }
  if (advice.error) { box.replaceChildren(el("p", { className: "meta" }, advice.error)); return; }
  const items = [];
  for (const s of advice.suggestions || []) {
    items.push(el("li", { className: "pin" }, `A window with ${s.orientation} would pin ${s.pins.join(", ")}.`));
  }
  for (const n of advice.unresolved || []) items.push(el("li", { className: "none" }, `${n}: no single extra orientation pins it; add more varied windows.`));
  const byReason = new Map();
  for (const h of advice.unseeable || []) byReason.set(h.reason, [...(byReason.get(h.reason) || []), h.direction]);
  for (const [reason, dirs] of byReason) {
    items.push(el("li", { className: "none" }, `No orientation can show ${dirs.length === 1 ? "this direction" : `these ${dirs.length} directions`}: ${reason}.`,
      el("ul", {}, ...dirs.map((d) => el("li", { className: "mono" }, d)))));
  }
  const head = (advice.weak || []).length || (advice.unseeable || []).length
    ? "Held or weakly seen in the current version:" : "Every coefficient is seen well by the stored windows.";
  box.replaceChildren(el("p", {}, head), el("ul", {}, ...items));
}

function renderResiduals() {
  const res = state.coverage?.residuals || [];
  const sel = $("residual-invariant");
  const keep = sel.value;
  sel.replaceChildren(...res.map((r) => el("option", { value: r.name }, `${r.name} (${r.unit})`)));
  sel.value = res.some((r) => r.name === keep) ? keep : res[0]?.name || "";
  const r = res.find((x) => x.name === sel.value);
  const chart = $("residual-chart");
  if (!r) { Plotly.purge(chart); chart.replaceChildren(el("p", { className: "meta" }, "No fit yet.")); return; }
  const nf = isNum(r.noise_floor) ? r.noise_floor : 0;
  const out = r.values.map((v) => Math.abs(v) > 3 * nf);
  Plotly.react(chart, [
    { x: r.ids, y: r.values, type: "bar", name: "residual",
      marker: { color: out.map((o) => (o ? COLORS.bad : COLORS.accent)) },
      hovertemplate: "window %{x}: %{y:.3g}<extra></extra>" },
    { x: [Math.min(...r.ids) - 0.5, Math.max(...r.ids) + 0.5], y: [nf, nf], mode: "lines", name: "±1σ noise",
      line: { color: COLORS.ok, dash: "dash", width: 1.5 }, hoverinfo: "skip" },
    { x: [Math.min(...r.ids) - 0.5, Math.max(...r.ids) + 0.5], y: [-nf, -nf], mode: "lines", showlegend: false,
      line: { color: COLORS.ok, dash: "dash", width: 1.5 }, hoverinfo: "skip" },
  ], layout({ xaxis: { title: { text: "window id" } }, yaxis: { title: { text: `${r.name} residual (${r.unit})` }, exponentformat: "power" },
    shapes: [{ type: "rect", xref: "paper", x0: 0, x1: 1, y0: -nf, y1: nf, fillcolor: "rgba(62,207,142,0.10)", line: { width: 0 } }] }), PLOT_CONFIG);
}

function renderDrift() {
  const d = state.drift || { points: [], last_reason: null };
  const r = d.last_reason;
  $("drift-reason").textContent = r ? `version ${r.version} (${r.accepted ? "accepted" : "rejected"}) ran because of ${r.text}` : "no job yet";
  const chart = $("drift-chart");
  const pts = d.points.filter((p) => isNum(p.statistic));
  if (!pts.length) {
    Plotly.purge(chart);
    chart.replaceChildren(el("p", { className: "meta" }, "No drift test yet: it runs on the windows after the first accepted version."));
    return;
  }
  const x = pts.map((p) => p.at);
  const text = pts.map((p) => `version ${p.version}, window ${p.window}${p.alarm && p.suspect ? `: looks like ${p.suspect}` : ""}`);
  Plotly.react(chart, [
    { x, y: pts.map((p) => p.statistic), mode: "lines+markers", name: "statistic", text,
      marker: { color: pts.map((p) => (p.alarm ? COLORS.bad : COLORS.accent)) },
      hovertemplate: "%{y:.1f}: %{text}<extra></extra>" },
    { x, y: pts.map((p) => p.threshold), mode: "lines", name: "threshold", line: { color: COLORS.bad, dash: "dash", width: 1.5, shape: "hv" },
      hovertemplate: "threshold %{y:.1f}<extra></extra>" },
  ], layout({ xaxis: { title: { text: "time (UTC)" }, type: "date" }, yaxis: { title: { text: "GLR statistic (chi-square)" }, type: "log" } }), PLOT_CONFIG);
}

function axisWord(g) {
  if (!g) return "-";
  const i = [0, 1, 2].reduce((a, b) => (Math.abs(g[b]) > Math.abs(g[a]) ? b : a), 0);
  const tilt = Math.acos(Math.min(1, Math.abs(g[i]))) * 180 / Math.PI;
  return `${"xyz"[i]} ${g[i] > 0 ? "down" : "up"}${tilt > 5 ? ` (${tilt.toFixed(0)}° off)` : ""}`;
}

function renderWindows() {
  const ws = (state.coverage?.windows || []).slice().reverse();
  $("windows").tBodies[0].replaceChildren(...ws.map((w) => el("tr", {},
    el("td", { className: "num" }, w.id), el("td", { className: "num" }, isNum(w.start_s) ? `${w.start_s.toFixed(0)} s` : "-"),
    el("td", { className: "num" }, isNum(w.end_s) && isNum(w.start_s) ? `${(w.end_s - w.start_s).toFixed(0)} s` : "-"),
    el("td", { className: "num" }, isNum(w.temperature_c) ? `${w.temperature_c.toFixed(1)} °C` : "-"),
    el("td", {}, axisWord(w.gravity)))));
}

// ---- health, counters, log ---------------------------------------------------------------------
// the running job: elapsed time and, for a swarm method, the Monte Carlo runs done
function jobWord(job) {
  if (!job) return "yes";
  const parts = [`${Math.round(job.elapsed_s)} s`];
  if (isNum(job.done) && isNum(job.total)) parts.push(`MC ${Math.floor(job.done)}/${job.total}`);
  return `yes (${parts.join(", ")})`;
}

function renderHealth(h) {
  const pill = $("health");
  pill.textContent = h.status === "ok" ? "health OK" : `health ${h.status.toUpperCase()}`;
  pill.className = `pill ${h.status === "ok" ? "pill-ok" : "pill-bad"}`;
  const probs = $("problems");
  probs.hidden = !h.problems.length;
  probs.textContent = h.problems.join("\n");
  const s = h.service || {};
  const last = s.scheduler?.last_job;
  const counters = [
    ["windows stored", h.positions], ["current version", h.current_version ?? "-"],
    ["frames", s.frames], ["windows this session", s.windows], ["slews", s.slews],
    ["spooled", s.windows_spooled], ["dropped", s.windows_dropped],
    ["recalibrating", s.recalibrating === undefined ? "-" : s.recalibrating ? jobWord(s.scheduler?.job) : "no"],
    ["last job", last ? `${last.status ?? last.state ?? "?"}` : "-"],
    ["uptime", isNum(s.uptime_s) ? (s.uptime_s < 3600 ? `${Math.floor(s.uptime_s / 60)} min` : `${(s.uptime_s / 3600).toFixed(1)} h`) : "-"],
  ];
  $("counters").replaceChildren(...counters.map(([k, v]) => el("div", {}, el("dt", {}, k),
    el("dd", {}, typeof v === "number" ? v.toLocaleString("en-GB") : v ?? "-"))));
  renderRefusals(s.detector);
  renderSync(h.sync);
}

// the fleet link (/health sync): its state, what waits in the outbox, and today's traffic
const SYNC_PILL = { up: "pill-ok", down: "pill-bad", rejected: "pill-bad", off: "pill-wait" };
function bytesWord(n) {
  if (!isNum(n)) return "-";
  return n < 1024 ? `${n} B` : n < 1048576 ? `${(n / 1024).toFixed(1)} KiB` : `${(n / 1048576).toFixed(1)} MiB`;
}
function renderSync(sync) {
  if (!sync || typeof sync !== "object") return;
  const pill = $("sync-state");
  pill.textContent = sync.state === "off" ? "off" : `link ${sync.state}`;
  pill.className = `pill ${SYNC_PILL[sync.state] || "pill-wait"}`;
  $("sync-where").textContent = sync.state === "off"
    ? "No [sync] section: nothing is sent to the shore."
    : `${sync.unit} to ${sync.url}`;
  const week = (sync.bytes_per_day || []).reduce((a, d) => a + (isNum(d.bytes) ? d.bytes : 0), 0);
  const rows = [
    ["backlog (rows to send)", isNum(sync.backlog) ? sync.backlog.toLocaleString("en-GB") : "-"],
    ["last contact", sync.last_contact ? sync.last_contact.replace("T", " ").slice(0, 19) + " UTC" : "never"],
    ["sent today", bytesWord(sync.bytes_today)], ["sent in 7 days", bytesWord(week)],
  ];
  $("sync-counters").replaceChildren(...rows.map(([k, v]) => el("div", {}, el("dt", {}, k), el("dd", {}, v))));
  const err = $("sync-error");
  err.hidden = !sync.last_error;
  err.textContent = sync.last_error || "";
}

// what the detector refused, by reason (/health service.detector: the rest check's turning,
// swinging, rate_low, accelerating among them) and, for the hull detector, its blocks by state
function renderRefusals(d) {
  const box = $("refusals");
  if (!d || typeof d !== "object") { box.hidden = true; return; }
  const rows = Object.entries(d.rejected || {}).filter(([, n]) => isNum(n) && n > 0)
    .map(([why, n]) => [`refused: ${why.replace(/_/g, " ")}`, n]);
  const b = d.blocks;
  if (b && isNum(b.total) && b.total > 0) {
    const s = isNum(d.block_s) ? d.block_s : 0.5;
    rows.push(["time turning", `${Math.round(b.turning * s)} s`], ["time accelerating", `${Math.round(b.accelerating * s)} s`]);
  }
  if (!rows.length) rows.push(["refused", 0]);
  $("refusals-head").textContent = `${d.motion === "hull" ? "Hull" : "Still"} detector · ${d.rest_check ? `rest check: ${d.rest_check}` : "no rest check (outputs not in deg/h and g)"}`;
  $("refusal-counts").replaceChildren(...rows.map(([k, v]) => el("div", {}, el("dt", {}, k),
    el("dd", {}, typeof v === "number" ? v.toLocaleString("en-GB") : v))));
  box.hidden = false;
}

function renderLog(events) {
  $("log").tBodies[0].replaceChildren(...events.map((e) => el("tr", {},
    el("td", { className: "when" }, e.created_at.replace("T", " ").slice(0, 19)),
    el("td", { className: "kind" }, e.kind), el("td", {}, e.message))));
}

// ---- loading and live updates ------------------------------------------------------------------
async function loadVersions() {
  state.history = await getJSON("coefficients/history?full=true&limit=100");
  state.newest = state.history[0]?.version ?? null;
  try { state.current = await getJSON("coefficients"); } catch (e) { if (e.status !== 404) throw e; state.current = null; }
  const prior = state.current?.prior_version;
  state.previous = prior ? state.history.find((r) => r.version === prior) || await getJSON(`coefficients/${prior}`) : null;
  state.coverage = await getJSON("dashboard/coverage");
  state.drift = await getJSON("dashboard/drift");
  renderCurrent(); renderHistory(); renderCoverage(); renderResiduals(); renderWindows(); renderDrift();
}

async function poll() {
  try {
    const [h, log, newest] = await Promise.all([getJSON("health"), getJSON("log?limit=50"), getJSON("coefficients/history?limit=1")]);
    renderHealth(h); renderLog(log);
    const v = newest[0]?.version ?? null;
    const windows = state.coverage?.windows.length;
    if (v !== state.newest || (h.positions >= 0 && h.positions !== windows)) await loadVersions(); // a rejected version or new windows
  } catch (e) {
    $("health").textContent = "service unreachable";
    $("health").className = "pill pill-bad";
  }
}

function listen() {
  const live = $("live");
  const source = new EventSource("events");
  source.onopen = () => { live.textContent = "live"; live.className = "pill pill-ok"; };
  source.onerror = () => { live.textContent = "reconnecting"; live.className = "pill pill-bad"; };
  source.addEventListener("coefficients", (ev) => {
    const data = JSON.parse(ev.data);
    if (data.version !== state.current?.version) loadVersions().catch(console.error);
  });
}

async function trigger(ev) {
  ev.preventDefault();
  const token = $("token").value.trim();
  if (token) sessionStorage.setItem("recal-token", token); else sessionStorage.removeItem("recal-token");
  const out = $("trigger-result");
  const button = $("recalibrate");
  button.disabled = true;
  out.className = ""; out.textContent = "sending...";
  try {
    const headers = { "Content-Type": "application/json", Accept: "application/json" };
    if (token) headers.Authorization = `Bearer ${token}`;
    const r = await fetch("recalibrate", { method: "POST", headers, body: "{}" });
    const body = await r.json().catch(() => ({}));
    if (r.ok) { out.className = "queued"; out.textContent = `queued: job ${body.job}`; }
    else { out.className = "refused"; out.textContent = `refused (${r.status}): ${body.detail || r.statusText}`; }
  } catch (e) {
    out.className = "refused"; out.textContent = `failed: ${e.message}`;
  } finally { button.disabled = false; }
}

function start() {
  $("token").value = sessionStorage.getItem("recal-token") || "";
  $("trigger-form").addEventListener("submit", trigger);
  $("history-coef").addEventListener("change", renderHistory);
  $("residual-invariant").addEventListener("change", renderResiduals);
  loadVersions().catch((e) => { $("version-meta").textContent = `cannot load: ${e.message}`; });
  poll();
  setInterval(poll, POLL_MS);
  listen();
}
document.addEventListener("DOMContentLoaded", start);
