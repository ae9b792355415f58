// GSA-ISAR console: the fly-by in the target's orbital frame (the plan's phasing.verification.relative_motion),
// drawn as two SVG panels: along-track against radial, and along-track against cross-track. Loaded before
// console.js, whose helpers (esc, num, utc) it uses when it runs.
"use strict";

function niceStep(span) {
  const raw = span / 5, p = Math.pow(10, Math.floor(Math.log10(raw)));
  return [1, 2, 5, 10].map((m) => m * p).find((s) => s >= raw) || raw;
}

// One panel: x along-track, y the other axis (km), the target at the origin, a dot every 10 s, T_access marked.
function encounterPanel(rm, yKey, yName) {
  const W = 540, H = 300, L = 64, R = 16, T = 14, B = 40;
  const xs = rm.along_track_km, ys = rm[yKey];
  const lim = (v) => { const m = Math.max(...v.map(Math.abs), 1e-3); return [-1.08 * m, 1.08 * m]; };
  const [x0, x1] = lim(xs), [y0, y1] = lim(ys);
  const X = (v) => L + ((v - x0) / (x1 - x0)) * (W - L - R), Y = (v) => T + ((y1 - v) / (y1 - y0)) * (H - T - B);
  let g = `<rect x="${L}" y="${T}" width="${W - L - R}" height="${H - T - B}" class="plotbg"/>`;
  for (const [lo, hi, step, axis] of [[x0, x1, niceStep(x1 - x0), "x"], [y0, y1, niceStep(y1 - y0), "y"]]) {
    for (let v = Math.ceil(lo / step) * step; v <= hi; v += step) {
      const label = Math.abs(v) < 1e-9 ? "0" : Number(v.toPrecision(6)).toString();
      g += axis === "x"
        ? `<line x1="${X(v)}" x2="${X(v)}" y1="${T}" y2="${H - B}" class="gridline"/><text x="${X(v)}" y="${H - B + 15}" class="tick" text-anchor="middle">${label}</text>`
        : `<line x1="${L}" x2="${W - R}" y1="${Y(v)}" y2="${Y(v)}" class="gridline"/><text x="${L - 5}" y="${Y(v) + 4}" class="tick" text-anchor="end">${label}</text>`;
    }
  }
  g += `<text x="${(L + W - R) / 2}" y="${H - 6}" class="axisname" text-anchor="middle">along-track (km; the target's motion to the right)</text>`;
  g += `<text x="14" y="${(T + H - B) / 2}" class="axisname" text-anchor="middle" transform="rotate(-90 14 ${(T + H - B) / 2})">${yName} (km)</text>`;
  const pts = xs.map((x, k) => `${X(x).toFixed(1)},${Y(ys[k]).toFixed(1)}`).join("L");
  g += `<path class="flyby" d="M${pts}"/>`;
  rm.t_s.forEach((t, k) => {
    if (Math.abs(t % 10) < 1e-6 && t !== 0) {
      g += `<circle cx="${X(xs[k]).toFixed(1)}" cy="${Y(ys[k]).toFixed(1)}" r="2.5" class="flytick"><title>${t > 0 ? "+" : ""}${t} s</title></circle>`;
      if (Math.abs(t) % 30 < 1e-6) g += `<text x="${X(xs[k]).toFixed(1)}" y="${(Y(ys[k]) - 7).toFixed(1)}" class="tick" text-anchor="middle">${t > 0 ? "+" : ""}${t} s</text>`;
    }
  });
  const k0 = rm.t_s.findIndex((t) => Math.abs(t) < 1e-6);
  g += `<circle cx="${X(0)}" cy="${Y(0)}" r="5" class="flytarget"><title>the target</title></circle>`;
  if (k0 >= 0) {
    g += `<line x1="${X(xs[k0])}" y1="${Y(ys[k0])}" x2="${X(0)}" y2="${Y(0)}" class="flylos"/>`;
    g += `<circle cx="${X(xs[k0])}" cy="${Y(ys[k0])}" r="5" class="flynow"><title>the observer at T_access</title></circle>`;
  }
  return `<svg class="panel encounter" viewBox="0 0 ${W} ${H}" role="img" aria-label="fly-by, along-track against ${esc(yName)}">${g}</svg>`;
}

// v: a plan's phasing.verification, or a campaign scene's check (which has no relative speed).
function encounterCard(v, title = "The fly-by in the target's orbital frame") {
  const rm = v && v.relative_motion;
  if (!rm || !rm.t_s.length) return "";
  const k0 = rm.t_s.findIndex((t) => Math.abs(t) < 1e-6);
  const at = k0 >= 0 ? `radial ${num(rm.radial_km[k0], 1)}, along-track ${num(rm.along_track_km[k0], 1)}, cross-track ${num(rm.cross_track_km[k0], 1)} km` : "";
  const speed = v.relative_speed_km_s == null ? "" : `, passing at ${num(v.relative_speed_km_s, 2)} km/s`;
  return `<div class="card encountercard"><b>${esc(title)}</b>
    <span class="muted">(the observer ${rm.t_s[0]} s to +${rm.t_s[rm.t_s.length - 1]} s about T_access, a dot every 10 s; axes to
    different scales)</span><br>
    at T_access the observer is ${num(v.separation_km, 2)} km from the target (${at})${speed};
    closest ${num(v.closest_approach_km, 2)} km at ${utc(v.closest_approach_time)}; the optical tracker must follow
    ${num(v.target_angular_rate_deg_s, 2)} deg/s
    <div class="grid">${encounterPanel(rm, "radial_km", "radial, up")}${encounterPanel(rm, "cross_track_km", "cross-track, orbit normal")}</div>
    <div class="legend"><span><i class="sw-flyby"></i>the observer's path</span><span><i class="sw-flylos"></i>line of sight at T_access</span>
    <span>● the target, at the origin; ○ the observer at T_access</span></div></div>`;
}
