// The fleet re-analysis page: the newest `recal fleet reanalyse` JSON (GET
// /fleet/dashboard/reanalysis.json, the administrator's token), as tables. Every text from the
// service goes through textContent, never innerHTML.
"use strict";

const TOKEN_KEY = "recal-fleet-token";  // shared with the fleet page (same tab)

function el(tag, props, ...children) {
  const node = document.createElement(tag);
  Object.assign(node, props || {});
  for (const c of children) node.append(c instanceof Node ? c : String(c ?? ""));
  return node;
}
const $ = (id) => document.getElementById(id);
const isNum = (v) => typeof v === "number" && Number.isFinite(v);
const fig = (v) => (isNum(v) ? (Math.abs(v) >= 1e4 || (v !== 0 && Math.abs(v) < 1e-3) ? v.toExponential(2) : v.toPrecision(3)) : "-");
function token() { return sessionStorage.getItem(TOKEN_KEY) || ""; }

function head(table, names) {
  table.tHead.replaceChildren(el("tr", {}, ...names.map((n) => el("th", {}, n))));
}

function estimate(r) {
  if (!r || !r.estimate) return "-";
  return Object.entries(r.estimate).map(([k, v]) => `${k} ${fig(v)} ± ${fig(r.sigma?.[k])}`).join(", ");
}

function draw(doc) {
  $("generated").textContent = `${doc.created_at} · ${doc.scheduler ? `cluster ${doc.scheduler}` : "local"} · ${doc.workers} worker(s)`;
  const refit = doc.refit || null;
  const totals = [["units", doc.units.length], ["versions", doc.versions], ["windows read", doc.windows],
    ["drift alarms", doc.units.filter((u) => u.drift_alarm).length], ["outliers", doc.units.filter((u) => u.outlier).length]];
  if (refit) totals.push(["effects tried", refit.effects.join(", ")], ["method", refit.method]);
  $("totals").replaceChildren(...totals.flatMap(([k, v]) => [el("dt", {}, k), el("dd", {}, v)]));
  const verdicts = $("verdicts");
  head(verdicts, ["Model", "Effect", "Verdict", "Significant", "Tested", "Common value ± 1σ", "One value? (p)"]);
  const rows = [];
  for (const [model, byEffect] of Object.entries(refit?.models || {})) {
    for (const [effect, v] of Object.entries(byEffect)) {
      const same = v.homogeneity;
      const common = same ? Object.entries(same.value).map(([k, x]) => `${k} ${fig(x)} ± ${fig(same.sigma[k])}`).join(", ") : "-";
      rows.push(el("tr", {}, el("td", {}, model || "-"), el("td", { className: "mono" }, effect),
        el("td", {}, el("span", { className: `flag verdict-${v.verdict}` }, v.verdict)),
        el("td", {}, v.significant), el("td", {}, v.tested), el("td", { className: "reasons-cell" }, common),
        el("td", {}, same ? fig(same.p_value) : "-")));
    }
  }
  verdicts.tBodies[0].replaceChildren(...rows);
  $("verdicts-card").hidden = !refit;
  const units = $("units");
  head(units, ["Unit", "Model", "Windows", "Drift", "Outlier", "Effect", "chi2_red before → after", "Estimate ± 1σ", "Significant"]);
  const body = [];
  for (const u of doc.units) {
    const drift = u.drift === null ? "-" : u.drift_alarm ? "ALARM" : "ok";
    const base = [el("td", { className: "mono" }, u.unit), el("td", {}, u.model || "-"), el("td", {}, u.windows),
      el("td", {}, drift), el("td", {}, u.outlier ? "yes" : "no")];
    const effects = Object.entries(u.refit?.effects || {});
    if (!effects.length) {
      body.push(el("tr", {}, ...base, el("td", { colSpan: 4, className: "reasons-cell" }, u.refit?.error || "")));
      continue;
    }
    for (const [effect, r] of effects) {
      body.push(el("tr", {}, ...base, el("td", { className: "mono" }, effect),
        el("td", {}, `${fig(u.refit.chi2_red_before)} → ${fig(r.chi2_red_after)}`),
        el("td", { className: "reasons-cell" }, estimate(r)),
        el("td", {}, r.significant ? `YES (p ${fig(r.p_adjusted)})` : `no (p ${fig(r.p_adjusted)})`)));
    }
  }
  units.tBodies[0].replaceChildren(...body);
}

async function load() {
  const status = $("status");
  const headers = { Accept: "application/json" };
  if (token()) headers.Authorization = `Bearer ${token()}`;
  const r = await fetch("reanalysis.json", { headers });
  const problems = $("problems");
  if (!r.ok) {
    const body = await r.json().catch(() => ({}));
    status.textContent = r.status === 401 ? "token needed" : `${r.status}`;
    status.className = "pill pill-wait";
    problems.textContent = body.detail || r.statusText;
    problems.hidden = false;
    return;
  }
  problems.hidden = true;
  draw(await r.json());
  status.textContent = "loaded";
  status.className = "pill pill-ok";
}

document.addEventListener("DOMContentLoaded", () => {
  $("token-form").addEventListener("submit", (ev) => {
    ev.preventDefault();
    sessionStorage.setItem(TOKEN_KEY, $("token").value.trim());
    $("token").value = "";
    load();
  });
  if (token()) load();
});
