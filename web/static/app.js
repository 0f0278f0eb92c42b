// sfdrig live view: draws the frames the server sends (already decimated) and posts commands.
"use strict";

const $ = (id) => document.getElementById(id);
const COLORS = ["#2b6cb0", "#c05621", "#2f855a", "#805ad5", "#b83280", "#718096"];
// What the page has done, for tests and the benchmark (sample-to-screen latency).
window.sfdrig = { frames: 0, latencies: [], role: null, lastFrame: null, orbitPoints: 0 };

let role = null;
const plots = {};

// --- axes: every axis says its quantity and unit, and its ticks can be read -------------------
// A quantity q = { name, unit, prefixed }: a prefixed unit (m, N, V, m/s²) is shown with the SI
// prefix that makes the ticks numbers of 1 to 999 (a 20 um orbit: "displacement [um]", ticks 10,
// 20; 3 mm/s² of acceleration: "acceleration [mm/s²]"); every tick has the decimals its step
// needs, so no tick reads "0" for a value that is not and no two read alike. The label says the
// unit the ticks are in, found from what is plotted now (q may change: an amplitude in um or N).
const PREFIXES = [[1e-9, "n"], [1e-6, "u"], [1e-3, "m"], [1, ""], [1e3, "k"], [1e6, "M"]];
function decimalsFor(step) {
  if (!(step > 0)) return 0;
  let d = Math.max(0, -Math.floor(Math.log10(step)));
  const off = (k) => Math.abs(step * 10 ** k - Math.round(step * 10 ** k)) > 1e-6 * step * 10 ** k;
  while (d < 15 && off(d)) d++;  // a step of 2.5 needs one decimal, 0.25 two
  return d;
}
// 3 to 6 ticks at a step of 1, 2, 2.5 or 5 times a power of ten, whatever the height
function tickSplits(u, i, min, max) {
  if (!(max > min)) return [min];
  const e0 = Math.floor(Math.log10(max - min)) - 1;
  for (let e = e0; e <= e0 + 3; e++) {
    for (const m of [1, 2, 2.5, 5]) {
      const step = m * 10 ** e;
      const first = Math.ceil(min / step - 1e-9), last = Math.floor(max / step + 1e-9);
      if (last - first + 1 <= 6) {
        const out = [];
        for (let k = first; k <= last; k++) out.push(Number((k * step).toPrecision(12)));
        return out;
      }
    }
  }
  return [min, max];
}
function tickValues(q) {
  return (u, splits, i, space, incr) => {
    const step = splits.length > 1 ? splits[1] - splits[0] : incr;
    const big = splits.reduce((m, v) => (v == null ? m : Math.max(m, Math.abs(v))), 0);
    let f = 1, p = "";
    if (q.prefixed && big > 0) for (const [k, s] of PREFIXES) if (big >= k * (1 - 1e-9)) { f = k; p = s; }
    if (q.prefixed && big > 0 && big < PREFIXES[0][0]) { f = PREFIXES[0][0]; p = PREFIXES[0][1]; }
    const ax = u.axes[i];
    ax._unitShown = p + q.unit;
    ax._unitOf = q.unit;
    const d = decimalsFor(step / f);
    return splits.map((v) => {
      if (v == null) return "";
      const x = Math.abs(v) < step * 1e-6 ? 0 : v / f;  // -0.000 is 0
      return x.toFixed(d);
    });
  };
}
function axisLabel(q) {
  return (u, i) => {
    const ax = u.axes[i];
    return `${q.name} [${ax._unitOf === q.unit ? ax._unitShown : q.unit}]`;
  };
}
// the x axis (along the bottom) and a y axis wide enough for its longest tick
function xAxis(q) { return { label: axisLabel(q), splits: tickSplits, values: tickValues(q) }; }
function yAxis(q) {
  return { label: axisLabel(q), splits: tickSplits, values: tickValues(q),
    size: (u, values) => Math.max(50, 20 + 7 * Math.max(0, ...(values || []).map((v) => String(v).length))) };
}
const TIME_MS = { name: "time", unit: "ms" };
const FREQ_HZ = { name: "frequency", unit: "Hz" };

function lineOpts(names, width, height, q) {
  return {
    width, height, legend: { live: false }, cursor: { show: false },
    scales: { x: { time: false } },
    series: [{ label: "time [ms]" }].concat(names.map((n, i) => n.endsWith(" trip")
      ? { label: n, stroke: "#c53030", width: 1, dash: [6, 4] }  // the safety limit: a trip there
      : { label: n, stroke: COLORS[i % COLORS.length], width: 1.2 })),
    axes: [xAxis(TIME_MS), yAxis(q)],
  };
}

function ensurePlot(key, el, names, opts) {
  const p = plots[key];
  const sig = names.join(",");
  if (p && p.sig === sig) return p.u;
  if (p) p.u.destroy();
  const u = new uPlot(opts, [[]].concat(names.map(() => [])), $(el));
  plots[key] = { u, sig };
  return u;
}

function fmt(v, d) { return v === null || v === undefined || Number.isNaN(v) ? "-" : Number(v).toFixed(d); }

function showMessage(text, error) {
  const m = $("message");
  m.textContent = text;
  m.className = error ? "error" : "";
}

// --- traces --------------------------------------------------------------------------------
// plotted in SI (m, N, m/s², V): each axis picks its prefix from what it shows
const GROUPS = [
  ["force", "plot-force", (n, u) => u === "N" && n !== "hammer", { name: "force", unit: "N", prefixed: true }],
  ["disp", "plot-disp", (n, u) => u === "m", { name: "displacement", unit: "m", prefixed: true }],
  ["acc", "plot-acc", (n, u) => u === "m/s^2", { name: "acceleration", unit: "m/s²", prefixed: true }],
];
const DRIVE_V = { name: "drive", unit: "V", prefixed: true };

function drawTraces(tr, status) {
  const units = status.units || {};
  const w = Math.max(380, $("plot-force").parentElement.clientWidth - 14);
  const safety = status.safety || {};
  // the trip levels drawn on the traces they apply to: load on the forces, volts on the drives
  // the displacement's (a radius, drawn on each axis's trace) only once a trace reaches a
  // quarter of it: drawn always it would flatten a trace of a few um into a line
  const dispLimit = safety.displacement_limit_m || null;  // [m]
  const limits = { force: safety.load_limit_n, drive: safety.drive_limit_v, disp: dispLimit };
  const peakOf = (data) => data.reduce((m, d) => d.reduce((a, v) => Math.max(a, Math.abs(v)), m), 0);
  const withLimit = (key, names, data, peak) => {
    const lim = limits[key];
    if (!lim || (key === "disp" && peak < 0.25 * lim)) return [names, data];
    return [names.concat(["+ trip", "- trip"]), data.concat([tr.t_ms.map(() => lim), tr.t_ms.map(() => -lim)])];
  };
  for (const [key, el, pick, q] of GROUPS) {
    const picked = Object.keys(tr.channels).filter((n) => pick(n, units[n]));
    const traces = picked.map((n) => tr.channels[n]);
    const peak = key === "disp" ? peakOf(traces) : null;  // once a frame, for the line and the words
    const [names, data] = withLimit(key, picked, traces, peak);
    const u = ensurePlot(key, el, names, lineOpts(names, w, 190, q));
    u.setData([tr.t_ms].concat(data));
    if (key === "disp") {
      $("disp-info").textContent = dispLimit
        ? `trip at ${fmt(dispLimit * 1e6, 1)} um (orbit radius): largest here ${fmt(peak * 1e6, 2)} um, ` +
          `${fmt(100 * peak / dispLimit, 0)} % of it` + (peak < 0.25 * dispLimit ? " (trip lines drawn from 25 %)" : "")
        : "";
    }
  }
  const [drives, ddata] = withLimit("drive", tr.drives || [], (tr.drives || []).map((n) => tr.channels[n]));
  const ud = ensurePlot("drive", "plot-drive", drives, lineOpts(drives, w, 190, DRIVE_V));
  ud.setData([tr.t_ms].concat(ddata));
}

// --- orbit (canvas: an x-y path with two circles) ------------------------------------------
function drawOrbit(tr, status) {
  const c = $("orbit");
  const g = c.getContext("2d");
  const safety = status.safety || {};
  const clearance = (safety.radial_clearance_m || 127e-6) * 1e6;
  const limit = (safety.displacement_limit_m || clearance * 0.5e-6) * 1e6;
  const xs = tr ? tr.orbit_x_um : [];
  const ys = tr ? tr.orbit_y_um : [];
  // centre the orbit on its mean: the probes' static offset is not motion
  const mx = xs.length ? xs.reduce((a, b) => a + b, 0) / xs.length : 0;
  const my = ys.length ? ys.reduce((a, b) => a + b, 0) / ys.length : 0;
  let rmax = 0;
  for (let i = 0; i < xs.length; i++) rmax = Math.max(rmax, Math.hypot(xs[i] - mx, ys[i] - my));
  // zoomed: the orbit fills the plot (an 8.8 um orbit is a dot inside the 127 um circle)
  const zoom = $("orbit-zoom").checked && rmax > 0;
  const r = zoom ? Math.max(1.0, rmax * 1.25) : clearance * 1.1;
  const s = c.width / (2 * r);
  const X = (x) => c.width / 2 + x * s;
  const Y = (y) => c.height / 2 - y * s;
  g.clearRect(0, 0, c.width, c.height);
  g.strokeStyle = "#e2e8f0"; g.lineWidth = 1;
  g.beginPath(); g.moveTo(0, c.height / 2); g.lineTo(c.width, c.height / 2);
  g.moveTo(c.width / 2, 0); g.lineTo(c.width / 2, c.height); g.stroke();
  g.strokeStyle = "#718096"; g.lineWidth = 1.5;
  g.beginPath(); g.arc(X(0), Y(0), clearance * s, 0, 2 * Math.PI); g.stroke();
  g.strokeStyle = "#c53030"; g.setLineDash([6, 4]);
  g.beginPath(); g.arc(X(0), Y(0), limit * s, 0, 2 * Math.PI); g.stroke();
  g.setLineDash([]);
  g.strokeStyle = "#2b6cb0"; g.lineWidth = 1.5;
  g.beginPath();
  for (let i = 0; i < xs.length; i++) {
    const px = X(xs[i] - mx), py = Y(ys[i] - my);
    if (i === 0) g.moveTo(px, py); else g.lineTo(px, py);
  }
  g.stroke();
  window.sfdrig.orbitPoints = xs.length;
  c.dataset.points = String(xs.length);
  c.dataset.rmaxUm = rmax.toFixed(3);
  c.dataset.scaleUm = r.toFixed(3);
  $("orbit-info").textContent = `clearance ${fmt(clearance, 1)} um, limit ${fmt(limit, 1)} um, orbit max radius ${fmt(rmax, 2)} um`
    + (zoom ? `; zoomed: ${fmt(r, 1)} um to the edge` : "");
}

// --- harmonics -----------------------------------------------------------------------------
function drawHarmonics(tr) {
  const h = (tr && tr.harmonics) || {};
  const names = ["x1", "y1", "fx", "fy"].filter((n) => h[n] && h[n][0] > 0);
  const w = Math.max(380, $("plot-harm").parentElement.clientWidth - 14);
  const u = ensurePlot("harm", "plot-harm", names, {
    width: w, height: 190, legend: { live: false }, cursor: { show: false },
    scales: { x: { time: false, range: [0.5, 5.5] }, y: { distr: 3, range: [1e-3, 200] } },
    axes: [{ label: "harmonic", values: (u, t) => t.map((v) => Number.isInteger(v) ? v + "X" : "") }, { size: 60, label: "% of 1X" }],
    series: [{ label: "harmonic" }].concat(names.map((n, i) => ({
      label: n, stroke: COLORS[i], width: 1.2,
      points: { show: true, size: 6, fill: COLORS[i] },
    }))),
  });
  u.setData([[1, 2, 3, 4, 5]].concat(names.map((n) => h[n].map((v) => Math.max(1e-3, 100 * v / h[n][0])))));
  const stale = document.body.classList.contains("stale");
  $("harm-info").textContent = tr && tr.triggered
    ? `${stale ? "NOT live: the last cycles received" : "live, over the cycles shown"} at ${fmt(tr.freq_hz, 2)} Hz`
    : "no drive: nothing to analyse";
}

// --- steps ---------------------------------------------------------------------------------
// the drive each step needed against the drive limit (the headroom), and the rig's dynamic
// stiffness F/X across the sweep
function drawDriveAndStiffness(sorted, status, w) {
  const f = sorted.map((s) => s.freq_hz);
  const lim = ((status || {}).safety || {}).drive_limit_v || null;
  const pts = (label, color) => ({ label, stroke: color, paths: () => null, points: { show: true, size: 7, fill: color } });
  const ud = ensurePlot("drivef", "plot-drive-f", ["drive", "limit"], {
    width: w, height: 190, legend: { live: false }, cursor: { show: false }, scales: { x: { time: false } },
    series: [{ label: "f [Hz]" }, pts("largest drive 1X [V]", COLORS[0]), { label: "drive limit [V]", stroke: "#c53030", dash: [6, 4] }],
    axes: [xAxis(FREQ_HZ), yAxis(DRIVE_V)],
  });
  ud.setData([f, sorted.map((s) => s.drive_v), f.map(() => lim)]);
  const worst = sorted.reduce((m, s) => (s.drive_v !== null && s.drive_v > m ? s.drive_v : m), 0);
  $("drive-info").textContent = lim && sorted.length
    ? `largest drive ${fmt(worst, 2)} V of ${fmt(lim, 1)} V: headroom ${fmt(lim - worst, 2)} V (${fmt(100 * (1 - worst / lim), 0)} %)` : "";
  const uk = ensurePlot("kf", "plot-k", ["kx re", "kx im", "ky re", "ky im"], {
    width: w, height: 190, legend: { live: false }, cursor: { show: false }, scales: { x: { time: false } },
    series: [{ label: "f [Hz]" }, pts("Re Kx", COLORS[0]), pts("Im Kx", COLORS[1]), pts("Re Ky", COLORS[2]), pts("Im Ky", COLORS[3])],
    axes: [xAxis(FREQ_HZ), yAxis({ name: "F/X", unit: "MN/m" })],
  });
  uk.setData([f, sorted.map((s) => s.kx_re_mn_per_m), sorted.map((s) => s.kx_im_mn_per_m),
    sorted.map((s) => s.ky_re_mn_per_m), sorted.map((s) => s.ky_im_mn_per_m)]);
}

// --- the transfer function across the sweep, from the recorded samples (server: web.transfer) ---
// Each step's X/F, F/X and coherence per driven axis; a step of low coherence is drawn grey
// and its value shown: its ratio is not to be trusted (noise, stick-slip, contact).
const LOW_GREY = "#a0aec0";
function transferSeries(points, axes, value) {
  // one column per axis for the trusted points, one grey column for the low-coherence ones
  const cols = axes.map((a) => points.map((p) => (p.axis === a && !p.low_coherence ? value(p) : null)));
  cols.push(points.map((p) => (p.low_coherence ? value(p) : null)));
  return cols;
}
function drawTransfer(panelId, out) {
  const panel = $(panelId);
  const points = out.points.slice().sort((a, b) => a.freq_hz - b.freq_hz || (a.axis < b.axis ? -1 : 1));
  const axes = [...new Set(points.map((p) => p.axis))].sort();
  const f = points.map((p) => p.freq_hz);
  const holder = panel.querySelector(".transfer-plots");
  const w = Math.max(300, Math.floor((panel.clientWidth - 40) / 2));
  const pts = (label, color, size) => ({ label, stroke: color, paths: () => null, points: { show: true, size: size || 7, fill: color } });
  const low = out.coherence_low;
  panel.querySelector(".coh-low").textContent = String(low);
  const plot = (key, q, series, columns, extra) => {
    const id = `${panelId}-${key}`;
    if (!$(id)) { const d = document.createElement("div"); d.id = id; holder.appendChild(d); }
    const u = ensurePlot(id, id, series.map((s) => s.label), {
      width: w, height: 190, legend: { show: true, live: false }, cursor: { show: false }, scales: { x: { time: false }, ...(extra || {}) },
      series: [{ label: "f [Hz]" }].concat(series), axes: [xAxis(FREQ_HZ), yAxis(q)] });
    u.setData([f].concat(columns));
  };
  const greyed = pts("low coherence", LOW_GREY, 9);
  const k = [];
  for (const [i, a] of axes.entries()) k.push(pts(`Re K${a}`, COLORS[2 * i]), pts(`Im K${a}`, COLORS[2 * i + 1]));
  const kCols = [];
  for (const a of axes) kCols.push(...transferSeries(points, [a], (p) => p.k_re_mn_per_m).slice(0, 1),
    ...transferSeries(points, [a], (p) => p.k_im_mn_per_m).slice(0, 1));
  plot("k", { name: "F/X", unit: "MN/m" }, k.concat([pts("low coh. Re", LOW_GREY, 9), pts("low coh. Im", LOW_GREY, 9)]),
    kCols.concat([points.map((p) => (p.low_coherence ? p.k_re_mn_per_m : null)), points.map((p) => (p.low_coherence ? p.k_im_mn_per_m : null))]));
  plot("h", { name: "|X/F|", unit: "um/kN" }, axes.map((a, i) => pts(`|${a.toUpperCase()}/F${a}|`, COLORS[i])).concat([greyed]),
    transferSeries(points, axes, (p) => p.h_um_per_kn));
  plot("phase", { name: "phase X/F", unit: "deg" }, axes.map((a, i) => pts(`${a} rel. f${a}`, COLORS[i])).concat([greyed]),
    transferSeries(points, axes, (p) => p.phase_deg));
  plot("coh", { name: "coherence", unit: "-" }, axes.map((a, i) => pts(`coherence ${a}`, COLORS[i])).concat([greyed, { label: "threshold", stroke: "#c53030", dash: [5, 4] }]),
    transferSeries(points, axes, (p) => p.coherence).concat([f.map(() => low)]), { y: { range: [0, 1.02] } });
  const lows = points.filter((p) => p.low_coherence);
  panel.querySelector(".transfer-info").textContent = (lows.length
    ? `low coherence: ${lows.map((p) => `${fmt(p.freq_hz, 1)} Hz ${p.axis}: ${fmt(p.coherence, 2)}`).join(", ")}`
    : (points.length ? `coherence ${low} or more at every step` : "no step recorded yet"))
    + (out.pending ? `; ${out.pending} step(s) not yet in the file` : "");
  const body = panel.querySelector(".transfer-table").tBodies[0];
  body.innerHTML = "";
  for (const p of out.points) {
    const tr = body.insertRow();
    tr.dataset.index = p.index; tr.dataset.axis = p.axis;
    if (p.low_coherence) tr.className = "low-coh";
    for (const c of [p.index + 1, fmt(p.freq_hz, 1), p.axis, fmt(p.h_um_per_kn, 3), fmt(p.phase_deg, 1),
      fmt(p.k_re_mn_per_m, 4), fmt(p.k_im_mn_per_m, 4), p.coherence === null ? "-" : fmt(p.coherence, 3), p.segments]) {
      tr.insertCell().textContent = String(c);
    }
    tr.cells[7].className = "coh";
  }
  panel.dataset.points = String(out.points.length);
  panel.dataset.run = out.run_id;
}
// live: the running (or last) run's file is read again at each new step, and while the
// writer has not flushed a step's samples yet (at most once a second)
let transferKey = null; let transferBusy = false; let transferAt = 0;
async function followTransfer(fr) {
  const st = fr.status || {};
  const run = st.run_id || (st.last_run && st.last_run.run_id) || "";
  if (!run || transferBusy) return;
  const key = `${run}|${fr.steps.length}`;
  const again = window.sfdrig.transferPending && Date.now() - transferAt > 1000;
  if (key === transferKey && !again) return;
  transferBusy = true; transferAt = Date.now();
  try {
    const out = await getJson(`/api/runs/${encodeURIComponent(run)}/transfer`);
    if (out.ok) {
      drawTransfer("transfer-live", out);
      window.sfdrig.transferPending = out.pending > 0 || out.status === "running" && out.steps < fr.steps.length;
      window.sfdrig.transferLoaded = (window.sfdrig.transferLoaded || 0) + 1;
      transferKey = key;
    } else {
      $("transfer-live").querySelector(".transfer-info").textContent = out.error;
      transferKey = key;
    }
  } finally { transferBusy = false; }
}

// a step's amplitude (um of displacement or N of load) plotted in SI: (factor, axis quantity)
const AMPLITUDE = { name: "amplitude", unit: "m", prefixed: true };
function amplitudeAxis(unit) {
  if (unit === "um") return [1e-6, { name: "amplitude", unit: "m", prefixed: true }];
  if (unit === "N") return [1, { name: "amplitude", unit: "N", prefixed: true }];
  return [1, { name: "amplitude", unit: unit || "um or N", prefixed: false }];
}
function times(v, k) { return v === null || v === undefined ? null : v * k; }  // a gap stays a gap
function drawSteps(steps, status) {
  const sorted = steps.slice().sort((a, b) => a.freq_hz - b.freq_hz);
  const f = sorted.map((s) => s.freq_hz);
  const w = Math.max(380, $("plot-amp").parentElement.clientWidth - 14);
  drawDriveAndStiffness(sorted, status, w);
  const pts = (label, color) => ({ label, stroke: color, paths: () => null, points: { show: true, size: 7, fill: color } });
  const unit = steps.length ? steps[0].unit : "";
  const [k, q] = amplitudeAxis(unit);
  Object.assign(AMPLITUDE, q);  // the plot's axis follows the run's unit
  const ua = ensurePlot("amp", "plot-amp", ["achieved", "target"], {
    width: w, height: 190, legend: { live: false }, cursor: { show: false }, scales: { x: { time: false } },
    series: [{ label: "f [Hz]" }, pts("achieved", COLORS[0]), pts("target", "#999")],
    axes: [xAxis(FREQ_HZ), yAxis(AMPLITUDE)],
  });
  ua.setData([f, sorted.map((s) => times(s.achieved, k)), sorted.map((s) => times(s.target, k))]);
  plots.amp.u.series[1].label = `achieved [${unit}]`;
  $("amp-unit").textContent = unit || "um or N";
  const band = steps.length ? steps[steps.length - 1].band_pct : 1;
  const ue = ensurePlot("err", "plot-err", ["error", "+band", "-band"], {
    width: w, height: 190, legend: { live: false }, cursor: { show: false }, scales: { x: { time: false } },
    series: [{ label: "f [Hz]" }, pts("error [%]", COLORS[0]),
      { label: "+tol", stroke: "#c53030", dash: [5, 4] }, { label: "-tol", stroke: "#c53030", dash: [5, 4] }],
    bands: [{ series: [2, 3], fill: "rgba(72,187,120,0.15)" }],
    axes: [xAxis(FREQ_HZ), yAxis({ name: "error", unit: "%" })],
  });
  ue.setData([f, sorted.map((s) => s.error_pct), f.map(() => band), f.map(() => -band)]);
  const withTarget = sorted.filter((s) => s.phase_target_deg !== null);
  const up = ensurePlot("phase", "plot-phase", ["phase", "target", "+band", "-band"], {
    width: w, height: 190, legend: { live: false }, cursor: { show: false }, scales: { x: { time: false } },
    series: [{ label: "f [Hz]" }, pts("phase [deg]", COLORS[1]), { label: "target", stroke: "#999" },
      { label: "+tol", stroke: "#c53030", dash: [5, 4] }, { label: "-tol", stroke: "#c53030", dash: [5, 4] }],
    bands: [{ series: [3, 4], fill: "rgba(72,187,120,0.15)" }],
    axes: [xAxis(FREQ_HZ), yAxis({ name: "phase", unit: "deg" })],
  });
  const tgt = sorted.map((s) => s.phase_target_deg);
  up.setData([f, sorted.map((s) => s.phase_deg), tgt,
    sorted.map((s) => s.phase_target_deg === null ? null : s.phase_target_deg + s.phase_band_deg),
    sorted.map((s) => s.phase_target_deg === null ? null : s.phase_target_deg - s.phase_band_deg)]);
  $("phase-info").textContent = steps.length
    ? `${steps[steps.length - 1].phase_label}` + (withTarget.length ? "" : " (not controlled: no target)")
    : "";
  const body = $("steps").tBodies[0];
  if (body.rows.length !== steps.length) {
    body.innerHTML = "";
    for (const s of steps) {
      const tr = body.insertRow();
      const bad = !s.converged || (s.error_pct !== null && Math.abs(s.error_pct) > s.band_pct);
      for (const c of stepCells(s)) tr.insertCell().textContent = String(c);
      if (bad) tr.cells[5].className = "bad";
    }
  }
}

// --- header, events ------------------------------------------------------------------------
function clock(t) { return t ? new Date(t * 1000).toLocaleTimeString() : "-"; }
function ago(s) { return s >= 60 ? `${Math.floor(s / 60)} min ${Math.round(s % 60)} s` : `${fmt(s, 1)} s`; }

// The link to the daemon, always in view: a daemon that is gone must look gone. The server
// judges it (heartbeats, the state file, a status poll); this draws what it says.
function linkUp(fr) { const l = fr.link || {}; return l.state === "live" || l.state === "late"; }
function drawLink(fr) {
  const l = fr.link || {};
  const up = linkUp(fr);
  $("link").textContent = { live: "live", late: "late", lost: "LOST", connecting: "connecting", reconnecting: "reconnecting" }[l.state] || String(l.state);
  $("link").className = "link " + (l.state || "");
  $("link").title = l.message || `heartbeat ${fmt(l.heartbeat_age_s, 1)} s ago`;
  $("data-age").textContent = l.last_data_time == null ? "none yet"
    : l.stale ? `none since ${clock(l.last_data_time)} (${ago(l.data_age_s)} ago)` : `${fmt(l.data_age_s, 1)} s old`;
  $("link-banner").hidden = up;
  if (!up) {
    $("link-banner").textContent = `Daemon ${l.state === "lost" ? "LOST" : l.state}: ${l.message}. `
      + (l.last_data_time ? `Last data at ${clock(l.last_data_time)}. ` : "") + "Nothing below is live.";
  }
  document.body.classList.toggle("stale", !!l.stale);
  const note = l.last_data_time ? `not live: last data at ${clock(l.last_data_time)} (${ago(l.data_age_s)} ago)` : "not live: no data yet";
  for (const n of document.querySelectorAll(".stale-note")) n.textContent = note;
  if (l.malformed) $("lost").title = `${l.malformed} malformed messages skipped; last: ${l.malformed_last}`;
}

function drawStatus(fr) {
  const st = fr.status || {};
  const p = st.progress || {};
  const up = linkUp(fr);
  drawLink(fr);
  $("board").textContent = (st.board && st.board.description) || "?";  // which board (daq.board)
  $("state").textContent = up ? (st.state || "?") : `unknown (was ${st.state || "?"})`;
  $("state").className = "state " + (up ? (st.state || "") : "lost");
  const runText = st.run_id || (st.last_run && st.last_run.run_id ? `(last: ${st.last_run.run_id} ${st.last_run.status})` : "-");
  $("run-id").textContent = up ? runText : `${runText} (last known)`;
  const total = p.steps_total || 0;
  const done = Math.max(p.steps_done || 0, st.run_id ? fr.steps.length : 0);
  $("step").textContent = up && st.run_id && p.step_index >= 0
    ? `${p.step_index + 1}/${total} at ${fmt(p.freq_hz, 1)} Hz, ${p.updates || 0} updates` : "-";
  $("progress").textContent = st.run_id ? `${done}/${total} steps` : "-";
  $("progress-fill").style.width = total && st.run_id ? `${100 * done / total}%` : "0";
  const left = fr.time_left_s;
  $("time-left").textContent = left === null ? "-" : left >= 60 ? `${Math.floor(left / 60)} min ${Math.round(left % 60)} s` : `${Math.round(left)} s`;
  $("pump").textContent = up ? (st.pump_on ? "ON" : "off") : "?";
  followState(st, up);
  const means = (fr.traces && fr.traces.means) || {};
  $("p-in").textContent = means.p_in === undefined || means.p_in === null ? "" : `inlet ${fmt(means.p_in / 1e3, 1)} kPa`;
  const lost = Object.values(fr.lost || {}).reduce((a, b) => a + b, 0);
  const bad = (fr.link || {}).malformed || 0;
  $("lost").textContent = bad ? `${lost} (+${bad} malformed)` : String(lost);
  // the run's peak orbit and load and any journal-housing contact (the daemon's summary once
  // the run has ended)
  const pk = fr.peaks;
  $("peaks").hidden = !pk;
  if (pk) {
    $("peaks").textContent = `run ${pk.run_id}${pk.final ? "" : " (so far)"}: ${pk.text}`;
    $("peaks").className = pk.contact || pk.tripped ? "bad" : "";
  }
  drawEvents(fr.events);
  drawLevels(fr.traces, st);
}

// --- inputs: RMS, peak and range used over the shown cycles ----------------------------------
function drawLevels(tr, st) {
  const levels = (tr && tr.levels) || {};
  const units = st.units || {};
  const body = $("levels").tBodies[0];
  body.innerHTML = "";
  for (const [name, l] of Object.entries(levels)) {
    const um = units[name] === "m";  // displacements in um
    const k = um ? 1e6 : 1;
    const mean = ((tr.means || {})[name]);
    const row = body.insertRow();
    row.dataset.input = name;
    for (const c of [name, um ? "um" : (units[name] || ""), fmt(mean === null || mean === undefined ? null : mean * k, 3),
      fmt(l.rms === null ? null : l.rms * k, 3), fmt(l.peak === null ? null : l.peak * k, 3), fmt(l.range_pct, 1)]) {
      row.insertCell().textContent = String(c);
    }
    if (l.range_pct !== null && l.range_pct > 90) row.cells[5].className = "bad";
  }
}

// --- events: filtered by kind, the shown ones exported --------------------------------------
let shownEvents = [];
function drawEvents(events) {
  const kinds = $("event-filter").value ? $("event-filter").value.split(",") : null;
  shownEvents = events.filter((e) => !kinds || kinds.includes(e.kind));
  const ev = $("events");
  ev.innerHTML = "";
  for (const e of shownEvents.slice().reverse()) {
    const li = document.createElement("li");
    li.className = "ev-" + e.kind;
    li.textContent = `${new Date(e.time * 1000).toLocaleTimeString()} ${e.kind}: ${e.message}`;
    ev.appendChild(li);
  }
}
$("event-filter").onchange = () => { const f = window.sfdrig.lastFrame; if (f) drawEvents(f.events); };
$("events-export").onclick = () => {
  const q = (v) => `"${String(v).replace(/"/g, '""')}"`;
  const lines = ["time_utc,kind,message,run_id"].concat(shownEvents.map((e) =>
    [new Date(e.time * 1000).toISOString(), e.kind, e.message, e.run_id || ""].map(q).join(",")));
  const a = document.createElement("a");
  a.href = URL.createObjectURL(new Blob([lines.join("\n") + "\n"], { type: "text/csv" }));
  a.download = "sfdrig-events.csv";
  a.click();
  setTimeout(() => URL.revokeObjectURL(a.href), 10000);
};

// --- the operator's question (the operator protocol; the terminal is the other front end) ----
const CHOICE_LABELS = { ok: "Accept", repeat: "Repeat point", skip: "Skip point", abort: "Abort test",
  reject: "Reject hit", double: "Simulated double hit", overload: "Simulated overload" };
let drawnQuestion = 0;
function drawQuestion(q) {
  $("question").hidden = !q;
  if (!q) { drawnQuestion = 0; return; }
  if (q.id === drawnQuestion) return;  // keep what is being typed
  drawnQuestion = q.id;
  $("q-where").textContent = q.where;
  $("q-id").textContent = `#${q.id}`;
  $("q-prompt").textContent = q.prompt;
  const info = $("q-info");
  info.innerHTML = "";
  for (const line of q.info || []) { const li = document.createElement("li"); li.textContent = line; info.appendChild(li); }
  $("q-shows").hidden = !q.shows;
  $("q-shows").textContent = q.shows ? `the simulated instrument shows: ${q.shows}` : "";
  const entry = q.entry;
  $("q-entry-label").hidden = !entry;
  $("q-entry").value = "";
  if (entry) { $("q-entry-name").textContent = entry.label; $("q-unit").textContent = `[${entry.unit}]`; }
  $("q-trigger").hidden = !q.trigger;
  const buttons = $("q-buttons");
  buttons.innerHTML = "";
  for (const c of q.choices) {
    const b = document.createElement("button");
    b.id = `q-${c}`;
    b.textContent = c === "ok" && entry ? "Enter" : c === "ok" && q.trigger ? "Strike (simulated)" : (CHOICE_LABELS[c] || c);
    if (c === "abort") b.className = "danger";
    b.hidden = role !== "operator";
    b.onclick = () => answer(q, c);
    buttons.appendChild(b);
  }
  $("q-entry").onkeydown = (ev) => { if (ev.key === "Enter") answer(q, "ok"); };
}
async function answer(q, choice) {
  const text = choice === "ok" && q.entry ? $("q-entry").value : "";
  const out = await post("/api/command", { cmd: "answer", question_id: q.id, choice, text });
  if (!out.ok) $("q-entry").select();
}

let drawnSteps = -1;
function onFrame(fr) {
  window.sfdrig.lastFrame = fr;
  // redraw the plots only when something new came (no new block between runs: the page idles)
  const stale = !!(fr.link || {}).stale;
  // also redrawn when the data turns stale: the labels then say it is not live
  const fresh = fr.block_seq !== window.sfdrig.lastBlockSeq || window.sfdrig.frames === 0
    || stale !== window.sfdrig.lastStale;
  window.sfdrig.lastBlockSeq = fr.block_seq;
  window.sfdrig.lastStale = stale;
  drawStatus(fr);
  followRuns(fr);
  followTransfer(fr);
  drawQuestion((fr.status || {}).question);
  if (fresh) {
    if (fr.traces) drawTraces(fr.traces, fr.status);
    drawOrbit(fr.traces, fr.status);
    drawHarmonics(fr.traces);
  }
  if (fresh || fr.steps.length !== drawnSteps) { drawSteps(fr.steps, fr.status); drawnSteps = fr.steps.length; }
  window.sfdrig.frames += 1;
  // sample-to-screen latency: from the daemon's acquisition of the newest block to this paint
  // (frames that bring no new block, e.g. between runs, are not counted)
  if (fr.t_acquired > 0 && fresh && !stale) {
    requestAnimationFrame(() => {
      const l = window.sfdrig.latencies;
      l.push(Date.now() / 1000 - fr.t_acquired);
      if (l.length > 100000) l.shift();
    });
  }
}

// --- controls ------------------------------------------------------------------------------
// Buttons follow the daemon's state: only what it takes now (its status's "allowed"), nothing
// while the link is down; the pump button that would change nothing is off.
const STARTS = ["start-example", "start-upload", "start-test"];
function followState(st, up) {
  const allowed = new Set(up ? (st.allowed || []) : []);
  for (const id of STARTS) $(id).disabled = !allowed.has("start");
  $("sweep-start").disabled = !checked || !allowed.has("start");
  for (const id of ["pause", "resume", "abort", "reset"]) $(id).disabled = !allowed.has(id);
  // a run holds the pump relay from its start to its end: the daemon refuses either switch
  const held = !!st.run_id;
  $("pump-on").disabled = !up || !!st.pump_on || held;
  $("pump-off").disabled = !up || !st.pump_on || held;
  for (const id of ["pump-on", "pump-off"]) $(id).title = held ? "the running run holds the pump relay until it ends" : "";
}

// Starting a run and switching the pump are confirmed first (abort never is).
let pending = null;
function confirmThen(text, action) {
  pending = action;
  $("confirm-text").textContent = text;
  $("confirm").hidden = false;
  $("confirm-yes").focus();
}
$("confirm-yes").onclick = () => { const a = pending; pending = null; $("confirm").hidden = true; if (a) a(); };
$("confirm-no").onclick = () => { pending = null; $("confirm").hidden = true; showMessage("cancelled", false); };
async function post(url, body) {
  let out;
  try {
    const r = await fetch(url, { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
    const text = await r.text();
    try { out = JSON.parse(text); } catch (e) { out = { ok: false, error: text || r.statusText }; }
  } catch (e) {
    out = { ok: false, error: String(e) };
  }
  showMessage(out.ok ? `${body.cmd || "start"}: ok` + (out.data && out.data.run_id ? ` (run ${out.data.run_id})` : "") : out.error, !out.ok);
  return out;
}

function setupControls(hello) {
  role = hello.role;
  window.sfdrig.role = role;
  $("who").textContent = `${hello.name} (${role})`;
  $("logout").hidden = !hello.login;
  $("controls").hidden = role !== "operator";
  $("editor").hidden = role !== "operator";
  if (role === "operator" && !sweepSchema) buildForm();
  $("viewer-note").hidden = role === "operator";
  const sel = $("example");
  sel.innerHTML = "";
  for (const n of hello.examples) { const o = document.createElement("option"); o.value = o.textContent = n; sel.appendChild(o); }
}

function pumpState() { const f = window.sfdrig.lastFrame; return f && f.status && f.status.pump_on ? "ON" : "off"; }
$("start-example").onclick = () => confirmThen(`Start the sweep ${$("example").value} (pump is ${pumpState()})?`,
  () => post("/api/start", { example: $("example").value }));
$("start-upload").onclick = async () => {
  const f = $("upload").files[0];
  if (!f) { showMessage("choose a sweep TOML file first", true); return; }
  const text = await f.text();
  confirmThen(`Start the sweep of ${f.name} (pump is ${pumpState()})?`,
    () => post("/api/start", { toml: text, filename: f.name }));
};
// "static:hand": the static test with the operator pushing and reading the force gauge
$("start-test").onclick = () => {
  const [test, by] = $("test-kind").value.split(":");
  confirmThen(`Start the ${$("test-kind").selectedOptions[0].textContent} test?`,
    () => post("/api/start_test", by ? { test, spec: { load_by: by } } : { test }));
};
$("pause").onclick = () => post("/api/command", { cmd: "pause" });
$("resume").onclick = () => post("/api/command", { cmd: "resume" });
$("abort").onclick = () => post("/api/command", { cmd: "abort" });
$("pump-on").onclick = () => confirmThen("Switch the oil pump ON?", () => post("/api/command", { cmd: "pump", on: true }));
$("pump-off").onclick = () => confirmThen("Switch the oil pump OFF?", () => post("/api/command", { cmd: "pump", on: false }));
$("reset").onclick = () => post("/api/command", { cmd: "reset" });

// --- a sweep defined on the page: a form built from the sweep model's schema -----------------
// Each number field's unit comes with the schema (the sweep model's own units): shown_unit, and
// shown_power, the power of ten the form shows the value times (a length in um: 6).
function kindOf(prop, defs) {
  const alts = prop.anyOf ? prop.anyOf.filter((a) => a.type !== "null") : [prop];
  const p = alts[0] || {};
  if (p.$ref) return ["object", defs[p.$ref.split("/").pop()]];
  if (p.enum) return ["enum", p.enum];
  if (p.const !== undefined) return ["enum", [p.const]];
  return [p.type === "array" ? "list" : p.type || "string", p];
}
let sweepSchema = null;
let checked = null;  // the last valid check: its spec, summary and TOML
function addFields(parent, props, defs, prefix) {
  for (const [name, prop] of Object.entries(props)) {
    const path = prefix + name;
    const [kind, info] = kindOf(prop, defs);
    if (kind === "object") {
      const fs = document.createElement("fieldset");
      const lg = document.createElement("legend");
      lg.textContent = `${name}: ${info.description || info.title || ""}`;
      fs.appendChild(lg);
      addFields(fs, info.properties, defs, path + ".");
      parent.appendChild(fs);
      continue;
    }
    const row = document.createElement("label");
    row.className = "row";
    row.title = prop.description || "";
    const fname = document.createElement("span");
    fname.className = "fname";
    fname.textContent = path;
    row.appendChild(fname);
    let input;
    if (kind === "enum") {
      input = document.createElement("select");
      for (const v of info) { const o = document.createElement("option"); o.value = o.textContent = v; input.appendChild(o); }
    } else {
      input = document.createElement("input");
      input.type = kind === "boolean" ? "checkbox" : "text";
      input.size = kind === "list" ? 28 : 12;
      if (kind === "list") input.placeholder = "values, comma-separated";
    }
    input.dataset.field = path;
    input.dataset.kind = kind;
    input.dataset.default = JSON.stringify(prop.default === undefined ? null : prop.default);
    input.dataset.power = String(prop.shown_power || 0);
    row.appendChild(input);
    const u = document.createElement("span");
    u.className = "unit";
    u.textContent = prop.shown_unit ? `[${prop.shown_unit}]` : "";
    row.appendChild(u);
    const err = document.createElement("span");
    err.className = "field-error";
    err.dataset.errorFor = path;
    row.appendChild(err);
    parent.appendChild(row);
    input.onchange = () => { checked = null; $("sweep-start").disabled = true; $("sweep-save").disabled = true; };
  }
}
function shown(power, v) {
  return power ? String(Number((v * 10 ** power).toPrecision(12))) : String(v);
}
function setForm(spec) {
  for (const input of document.querySelectorAll("#sweep-form [data-field]")) {
    const path = input.dataset.field;
    const power = Number(input.dataset.power);
    let v = JSON.parse(input.dataset.default);
    let cur = spec;
    for (const k of path.split(".")) cur = cur && typeof cur === "object" ? cur[k] : undefined;
    if (cur !== undefined) v = cur;
    if (input.dataset.kind === "boolean") input.checked = !!v;
    else if (v === null || v === undefined) input.value = "";
    else if (Array.isArray(v)) input.value = v.map((x) => shown(power, x)).join(", ");
    else input.value = typeof v === "number" ? shown(power, v) : String(v);
  }
}
function readForm() {
  const spec = {};
  for (const input of document.querySelectorAll("#sweep-form [data-field]")) {
    const path = input.dataset.field.split(".");
    const exp = Number(input.dataset.power) ? `e${-Number(input.dataset.power)}` : "";  // exact: "13e-6"
    const kind = input.dataset.kind;
    const num = (t) => { const x = Number(t.trim() + exp); return t.trim() === "" || Number.isNaN(x) ? t.trim() : x; };
    let v;
    if (kind === "boolean") v = input.checked;
    else if (input.value.trim() === "") continue;  // left empty: the model's default
    else if (kind === "list") v = input.value.split(/[,\s]+/).filter((t) => t !== "").map(num);
    else if (kind === "number" || kind === "integer") v = num(input.value);
    else v = input.value;
    let target = spec;
    for (const k of path.slice(0, -1)) target = target[k] = target[k] || {};
    target[path[path.length - 1]] = v;
  }
  return spec;
}
function showCheck(out) {
  for (const e of document.querySelectorAll("#sweep-form .field-error")) e.textContent = "";
  $("sweep-form-error").textContent = "";
  for (const e of out.errors || []) {
    // the nearest field of the error's path (freq_hz.0 -> freq_hz); "" : a rule between fields
    let path = e.field;
    let el = null;
    while (path && !(el = document.querySelector(`#sweep-form [data-error-for="${CSS.escape(path)}"]`))) {
      path = path.includes(".") ? path.slice(0, path.lastIndexOf(".")) : "";
    }
    (el || $("sweep-form-error")).textContent += (el && el.textContent ? "; " : "") + e.message;
  }
  checked = out.ok ? out : null;
  $("sweep-start").disabled = !out.ok;
  $("sweep-save").disabled = !out.ok;
  $("sweep-summary").textContent = out.ok ? summaryText(out.summary) : "";
}
function summaryText(m) {
  const lim = m.limits || {};
  return [`${m.name || "(no name)"}: ${m.motion}, hold ${m.target_kind} at ${m.targets.map((t) => fmt(t, 2)).join(", ")} ${m.target_unit}`,
    `${m.steps} steps: ${m.frequencies} frequencies from ${fmt(m.freq_first_hz, 2)} to ${fmt(m.freq_last_hz, 2)} Hz`,
    `settling and recording alone: ${duration(m.settle_record_s)} (each step's approach adds to it)`,
    `pump: must be ${m.pump.toUpperCase()} (${m.pump === "on" ? "a lubricated sweep needs inlet pressure" : "a dry sweep; refused while the film drains"})`,
    `tolerance +/-${m.tolerance_amplitude_pct} % amplitude, +/-${m.tolerance_phase_deg} deg phase; not converged: ${m.on_not_converged}`,
    `limits: orbit ${lim.displacement_limit_m ? fmt(lim.displacement_limit_m * 1e6, 1) + " um" : "?"}, load ${lim.load_limit_n ? fmt(lim.load_limit_n, 0) + " N" : "?"}, drive ${lim.drive_limit_v ? fmt(lim.drive_limit_v, 1) + " V" : "?"}`].join("\n");
}
async function postJson(url, body) {
  try {
    const r = await fetch(url, { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
    const text = await r.text();
    try { return JSON.parse(text); } catch (e) { return { ok: false, error: text || r.statusText, errors: [{ field: "", message: text || r.statusText }] }; }
  } catch (e) { return { ok: false, error: String(e), errors: [{ field: "", message: String(e) }] }; }
}
async function buildForm() {
  const out = await getJson("/api/sweep/schema");
  if (!out.ok) return;
  sweepSchema = out.schema;
  $("sweep-form").innerHTML = "";
  addFields($("sweep-form"), sweepSchema.properties, sweepSchema.$defs || {}, "");
  setForm({});
  window.sfdrig.formReady = true;
}
$("sweep-check").onclick = async () => showCheck(await postJson("/api/sweep/check", { spec: readForm() }));
$("sweep-defaults").onclick = () => { setForm({}); showCheck({ ok: false, errors: [] }); };
$("sweep-start").onclick = () => {
  if (!checked) return;
  const spec = checked.spec;
  confirmThen(`Start: ${summaryText(checked.summary).split("\n").join("; ")}?`, () => post("/api/start", { spec }));
};
$("sweep-save").onclick = () => {
  if (!checked) return;
  const a = document.createElement("a");
  a.href = URL.createObjectURL(new Blob([checked.toml], { type: "text/plain" }));
  a.download = (checked.spec.name || "sweep").replace(/[^A-Za-z0-9._-]+/g, "_") + ".toml";
  a.click();
  setTimeout(() => URL.revokeObjectURL(a.href), 10000);
};
$("sweep-load").onchange = async () => {
  const f = $("sweep-load").files[0];
  if (!f) return;
  const out = await postJson("/api/sweep/check", { toml: await f.text(), filename: f.name });
  if (out.spec) setForm(out.spec);
  showCheck(out);
};

// --- run history: the runs directory's runs, one opened from its file ---------------------------
function stepCells(s) {
  return [s.index + 1, fmt(s.freq_hz, 1), s.motion, `${fmt(s.target, 2)} ${s.unit}`,
    `${fmt(s.achieved, 2)} ${s.unit}`, fmt(s.error_pct, 2), fmt(s.phase_deg, 1), s.updates,
    s.converged ? "yes" : `no: ${s.reason}`];
}
function duration(sec) { return sec < 60 ? `${fmt(sec, 1)} s` : `${Math.floor(sec / 60)} min ${Math.round(sec % 60)} s`; }
async function getJson(url) {
  try {
    const r = await fetch(url);
    const text = await r.text();
    try { return JSON.parse(text); } catch (e) { return { ok: false, error: text || r.statusText }; }
  } catch (e) { return { ok: false, error: String(e) }; }
}
let openRunId = null;
let runsAsked = 0;
let runsOffset = 0;  // the page of the run list shown (newest first)
const RUNS_PAGE = 100;
async function loadRuns() {
  const mine = ++runsAsked;
  const ask = new URLSearchParams({ limit: RUNS_PAGE, offset: runsOffset });
  for (const [key, id] of [["kind", "runs-kind"], ["status", "runs-status"], ["lubricated", "runs-oil"], ["since", "runs-since"]])
    if ($(id).value) ask.set(key, $(id).value);  // the run index's filters (sfdrig runs')
  const out = await getJson(`/api/runs?${ask}`);
  if (mine !== runsAsked) return;  // a newer reload was asked meanwhile: its answer is drawn
  window.sfdrig.runsLoaded = (window.sfdrig.runsLoaded || 0) + 1;
  const body = $("runs").tBodies[0];
  body.innerHTML = "";
  if (!out.ok) { $("runs-info").textContent = out.error; return; }
  $("runs-info").textContent = `${out.total} in ${out.runs_dir}` + (out.total > out.runs.length
    ? ` (${out.offset + 1}-${out.offset + out.runs.length} shown, newest first)` : "");
  $("runs-newer").disabled = out.offset <= 0;
  $("runs-older").disabled = out.offset + out.runs.length >= out.total;
  for (const r of out.runs) {
    const tr = body.insertRow();
    tr.dataset.run = r.id;
    const cells = [r.id || r.file, r.date ? new Date(r.date).toLocaleString() : "-", r.kind || "-", r.steps,
      r.status + (r.error ? `: ${r.error}` : ""), duration(r.duration_s), r.notes || ""];
    for (const c of cells) tr.insertCell().textContent = String(c);
    tr.cells[4].className = "st-" + r.status;
    const open = document.createElement("button");
    open.textContent = "Open";
    open.disabled = !r.id;
    open.onclick = () => openRun(r.id);
    tr.insertCell().appendChild(open);
  }
}
async function openRun(id) {
  const run = await getJson(`/api/runs/${encodeURIComponent(id)}`);
  if (!run.ok) { showMessage(run.error, true); return; }
  openRunId = id;
  $("run").hidden = false;
  $("run-title").textContent = `${run.run_id} (${run.kind}, ${run.status})`;
  $("run-summary").textContent = `${run.start_time} to ${run.stop_time || "-"}, ${duration(run.duration_s || 0)}, `
    + `${run.steps.length} steps, operator ${run.operator || "-"}` + (run.status_reason ? `; ended: ${run.status_reason}` : "");
  for (const f of run.formats) $(`dl-${f}`).href = `/api/runs/${encodeURIComponent(id)}/download?format=${f}`;
  $("run-downloads").hidden = run.status === "running";
  const body = $("run-steps").tBodies[0];
  body.innerHTML = "";
  for (const s of run.steps) {
    const tr = body.insertRow();
    for (const c of stepCells(s)) tr.insertCell().textContent = String(c);
    if (!s.converged || (s.error_pct !== null && Math.abs(s.error_pct) > s.band_pct)) tr.cells[5].className = "bad";
  }
  const sorted = run.steps.slice().sort((a, b) => a.freq_hz - b.freq_hz);
  const unit = sorted.length ? sorted[0].unit : "";
  const [k, q] = amplitudeAxis(unit);
  const w = Math.max(380, $("run").clientWidth - 20);
  const pts = (label, color) => ({ label, stroke: color, paths: () => null, points: { show: true, size: 7, fill: color } });
  if (plots.runAmp) plots.runAmp.u.destroy();
  const u = new uPlot({ width: w, height: 200, legend: { live: false }, cursor: { show: false }, scales: { x: { time: false } },
    series: [{ label: "f [Hz]" }, pts(`achieved [${unit}]`, COLORS[0]), pts(`target [${unit}]`, "#999")],
    axes: [xAxis(FREQ_HZ), yAxis(q)] },
  [sorted.map((s) => s.freq_hz), sorted.map((s) => times(s.achieved, k)), sorted.map((s) => times(s.target, k))], $("plot-run-amp"));
  plots.runAmp = { u, sig: "" };
  drawNotes(run.notes);
  const tf = await getJson(`/api/runs/${encodeURIComponent(id)}/transfer`);
  if (tf.ok) drawTransfer("transfer-run", tf);
  else $("transfer-run").querySelector(".transfer-info").textContent = tf.error;
  const ev = $("run-events");
  ev.innerHTML = "";
  for (const e of run.events) { const li = document.createElement("li"); li.textContent = `${e.time} ${e.kind}: ${e.message}`; ev.appendChild(li); }
  $("note-form").hidden = role !== "operator";
  drawReport(id, run.report, run.status);
}
function drawReport(id, made, status) {
  $("report-open").hidden = !made;
  $("report-open").href = `/api/runs/${encodeURIComponent(id)}/report/index.html`;
  $("report-make").hidden = role !== "operator";
  $("report-make").disabled = status === "running";
  $("report-make").textContent = made ? "Make it again" : "Make the report";
  $("report-info").textContent = made ? "" : "none yet";
}
$("report-make").onclick = async () => {
  const id = openRunId;
  if (!id) return;
  $("report-make").disabled = true;
  $("report-info").textContent = "identifying (sfdrig identify) ...";
  let out;
  try {
    const r = await fetch(`/api/runs/${encodeURIComponent(id)}/report`, { method: "POST",
      headers: { "Content-Type": "application/json" }, body: "{}" });
    const text = await r.text();
    try { out = JSON.parse(text); } catch (e) { out = { ok: false, error: text || r.statusText }; }
  } catch (e) { out = { ok: false, error: String(e) }; }
  $("report-make").disabled = false;
  if (openRunId !== id) return;
  drawReport(id, out.ok, "");
  $("report-info").textContent = out.ok ? "made" : out.error;
};
function drawNotes(notes) {
  const ol = $("run-notes");
  ol.innerHTML = "";
  for (const n of notes) { const li = document.createElement("li"); li.textContent = `${clock(n.time)} ${n.author}: ${n.text}`; ol.appendChild(li); }
}
// trips, e-stops, watchdogs, contacts and interrupted runs across the runs directory's runs
function incidentQuery(format) {
  const q = new URLSearchParams();
  if ($("incident-filter").value) q.set("incident", $("incident-filter").value);
  if ($("incident-since").value) q.set("since", $("incident-since").value);
  if (format) q.set("format", format);
  return `/api/trips?${q}`;
}
// reloads overlap (the link's state changes fast while a daemon restarts): only the newest
// request's answer is drawn, never an older one that took longer
let incidentsAsked = 0;
async function loadIncidents() {
  $("incidents-export").href = incidentQuery("csv");
  const mine = ++incidentsAsked;
  const out = await getJson(incidentQuery(""));
  if (mine !== incidentsAsked) return;
  // a file being closed by a daemon right now may not read: asked again shortly
  if (!out.ok || out.unreadable) setTimeout(() => { if (mine === incidentsAsked) loadIncidents(); }, 2000);
  const body = $("incident-table").tBodies[0];
  body.innerHTML = "";
  window.sfdrig.incidentsLoaded = (window.sfdrig.incidentsLoaded || 0) + 1;
  if (!out.ok) { $("incidents-info").textContent = out.error; return; }
  $("incidents-info").textContent = `${out.incidents.length} shown of ${out.total}`
    + (out.unreadable ? `; ${out.unreadable} run file(s) unreadable` : "");
  for (const r of out.incidents) {
    const tr = body.insertRow();
    tr.className = `inc-${r.incident}`;
    tr.dataset.run = r.run_id;
    for (const c of [r.time_utc.replace("T", " ").slice(0, 23), r.run_id, r.incident, r.what, r.where,
      fmt(r.peak_orbit_um, 1), fmt(r.peak_load_n, 1)]) tr.insertCell().textContent = String(c);
    const cell = tr.insertCell();
    if (!r.run_id) continue;  // between runs: no run to open
    const open = document.createElement("button");
    open.textContent = "Open";
    open.onclick = () => openRun(r.run_id);
    cell.appendChild(open);
  }
}
$("incident-filter").onchange = loadIncidents;
$("incident-since").onchange = loadIncidents;
$("runs-refresh").onclick = () => { loadRuns(); loadIncidents(); };
$("runs-newer").onclick = () => { runsOffset = Math.max(0, runsOffset - RUNS_PAGE); loadRuns(); };
$("runs-older").onclick = () => { runsOffset += RUNS_PAGE; loadRuns(); };
for (const id of ["runs-kind", "runs-status", "runs-oil", "runs-since"]) $(id).onchange = () => { runsOffset = 0; loadRuns(); };
$("run-close").onclick = () => { $("run").hidden = true; openRunId = null; };
$("note-add").onclick = async () => {
  if (!openRunId) return;
  let out;
  try {
    const r = await fetch(`/api/runs/${encodeURIComponent(openRunId)}/notes`, { method: "POST",
      headers: { "Content-Type": "application/json" }, body: JSON.stringify({ text: $("note-text").value }) });
    const text = await r.text();
    try { out = JSON.parse(text); } catch (e) { out = { ok: false, error: text || r.statusText }; }
  } catch (e) { out = { ok: false, error: String(e) }; }
  showMessage(out.ok ? "note kept" : out.error, !out.ok);
  if (out.ok) { $("note-text").value = ""; drawNotes(out.notes); loadRuns(); }
};
// the list is read again when a run starts or ends and when the daemon comes back
let runsKey = null;
function followRuns(fr) {
  const st = fr.status || {};
  const key = [(fr.link || {}).state, st.run_id, st.last_run && st.last_run.run_id, st.last_run && st.last_run.status,
    st.pid, st.idle_incidents].join("|");  // (an e-stop between runs is in the daemon's incident log)
  if (key !== runsKey) { runsKey = key; loadRuns(); loadIncidents(); }
  // the running run's row follows it (the list was read when it started: 0 steps, 0.1 s)
  const row = st.run_id && linkUp(fr) ? document.querySelector(`#runs tbody tr[data-run="${CSS.escape(st.run_id)}"]`) : null;
  if (row) {
    row.cells[3].textContent = String((fr.steps || []).length);
    if (st.samples > 0 && st.sample_rate_hz > 0) row.cells[5].textContent = duration(st.samples / st.sample_rate_hz);
  }
}

const DRAWN_LATEST_MS = 250;  // the next frame is asked for by then even if not painted

async function loggedOut() {
  try { return (await fetch("/api/session")).status === 401; } catch (e) { return false; }
}
function connect() {
  const ws = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws");
  ws.onmessage = (ev) => {
    const m = JSON.parse(ev.data);
    if (m.type === "hello") setupControls(m);
    else if (m.type === "frame") {
      // ask for the next frame once this one is painted: a slow page skips frames instead of
      // letting them queue up (seconds late) in the network buffers. Whatever happens while
      // drawing, the next frame is asked for: after painting, or at the latest after
      // DRAWN_LATEST_MS (a page whose painting is held back, e.g. a hidden tab or a starved
      // headless browser, still gets the state and the operator's questions, at that pace)
      let asked = false;
      const ask = () => {
        if (!asked && ws.readyState === WebSocket.OPEN) { asked = true; ws.send("drawn"); }
      };
      try { onFrame(m); } finally {
        requestAnimationFrame(ask);
        setTimeout(ask, DRAWN_LATEST_MS);
      }
    }
  };
  ws.onclose = async (ev) => {
    if (ev.code === 4001) { location.assign("/login"); return; }  // the key was revoked
    // refused (no close code): a key revoked while the page was closed, or a restarted server
    // that forgot the login; the page then goes to the login instead of reconnecting for ever
    if (await loggedOut()) { location.assign("/login"); return; }
    // the web server itself is gone: nothing on the page is live any more
    document.body.classList.add("stale");
    $("link").textContent = "?"; $("link").className = "link lost";
    $("link-banner").hidden = false;
    $("link-banner").textContent = "The connection to sfdrig web is lost: nothing on this page is live. Reconnecting.";
    for (const id of STARTS.concat(["pause", "resume", "abort", "reset", "pump-on", "pump-off"])) $(id).disabled = true;
    showMessage("connection to sfdrig web lost; reconnecting", true);
    setTimeout(connect, 1000);
  };
}
connect();
$("orbit-zoom").onchange = () => { const f = window.sfdrig.lastFrame; if (f) drawOrbit(f.traces, f.status); };
