// GSA-ISAR console: plain JavaScript over the service's own /v1 API, no build step, nothing from a CDN.
// The API key is asked once per browser session (sessionStorage); "#key=..." in the address hands it over
// once and is then taken out of the address.
"use strict";

const view = document.getElementById("view");
const status = document.getElementById("status");
let failed = 0;
let pending = 0;

function esc(v) {
  return String(v ?? "").replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);
}
function utc(iso) {
  if (!iso) return "-";
  const d = new Date(iso);
  return isNaN(d) ? esc(iso) : d.toISOString().replace(".000Z", "Z");
}
function num(v, digits) {
  return v === null || v === undefined ? "-" : Number(v).toFixed(digits);
}
function fail(message) {
  failed += 1;
  status.dataset.failed = String(failed);
  view.insertAdjacentHTML("afterbegin", `<p class="error">${esc(message)}</p>`);
}
function settle() {
  if (pending === 0) status.dataset.ready = "1";
}

function takeKeyFromAddress() {
  const m = location.hash.match(/key=([^&]+)/);
  if (m) {
    sessionStorage.setItem("gsaKey", decodeURIComponent(m[1]));
    const rest = location.hash.replace(/[#&]?key=[^&]+/, "").replace(/^&/, "");
    history.replaceState(null, "", location.pathname + (rest.startsWith("#") ? rest : "#" + (rest || "/plans")));
  }
}
function key() {
  return sessionStorage.getItem("gsaKey");
}

async function api(path, as = "json", method = "GET") {
  pending += 1;
  status.dataset.ready = "0";
  try {
    const r = await fetch(path, { method, headers: { "X-API-Key": key() } });
    if (r.status === 401) {
      sessionStorage.removeItem("gsaKey");
      throw new Error("the API key was refused: enter a valid one");
    }
    if (!r.ok) {
      let detail = r.statusText;
      try {
        const body = await r.json();
        detail = Array.isArray(body.detail) ? body.detail.map((d) => `${d.loc.join(".")}: ${d.msg}`).join("; ") : body.detail;
      } catch (e) { /* not JSON */ }
      throw new Error(`${path}: ${r.status} ${detail}`);
    }
    return as === "blob" ? await r.blob() : as === "text" ? await r.text() : await r.json();
  } finally {
    pending -= 1;
    settle();
  }
}

function askForKey(refused = "") {
  document.getElementById("who").textContent = "";
  view.innerHTML = `<h1>API key</h1>${refused ? `<p class="error" id="refused">${esc(refused)}</p>` : ""}
    <div class="card"><p>Every request carries your API key (<code>X-API-Key</code>). It is kept in this browser tab
    only (sessionStorage) and goes to no other site. <code>gsa keys create NAME</code> makes one; <code>make run</code>
    prints a development key.</p>
    <form id="keyform"><input type="password" id="keyinput" placeholder="gsa_..." autocomplete="off">
    <button>Use this key</button></form></div>`;
  document.getElementById("keyform").addEventListener("submit", (ev) => {
    ev.preventDefault();
    sessionStorage.setItem("gsaKey", document.getElementById("keyinput").value.trim());
    route();
  });
  status.dataset.ready = "1";
}

// ---- plans
async function plansPage(params) {
  const target = params.get("target") || "";
  const q = new URLSearchParams({ limit: "50" });
  if (target) q.set("target_name", target);
  const body = await api(`/v1/plans?${q}`);
  const rows = body.data.map((p) => `<tr>
      <td><a href="#/plans/${esc(p.id)}">${esc(p.id.slice(0, 8))}</a></td><td>${utc(p.created_at)}</td>
      <td>${esc(p.target_name)}</td><td>${esc(p.observer_name)}</td><td>${esc(p.station_name)}</td>
      <td>${utc(p.t_access)}</td><td class="num">${num(p.dv_total_m_s, 1)}</td>
      <td>${p.feasible === null || p.feasible === undefined ? "-" : p.feasible ? "yes" : "no"}</td></tr>`).join("");
  view.innerHTML = `<h1>Plans <span class="muted">(${body.count})</span> <a class="action" href="#/new-plan">New plan</a></h1>
    <form class="filter" id="filter"><input type="text" id="target" placeholder="target name" value="${esc(target)}">
    <button>Filter</button></form>
    <table id="plans"><thead><tr><th>plan</th><th>created (UTC)</th><th>target</th><th>observer</th><th>station</th>
    <th>T_access (UTC)</th><th class="num">dv (m/s)</th><th>feasible</th></tr></thead><tbody>${rows ||
      '<tr><td colspan="8" class="muted">No plans yet: POST /v1/plans, or gsa plan --server.</td></tr>'}</tbody></table>`;
  document.getElementById("filter").addEventListener("submit", (ev) => {
    ev.preventDefault();
    const t = document.getElementById("target").value.trim();
    location.hash = "#/plans" + (t ? "?target=" + encodeURIComponent(t) : "");
  });
}

const W = 1080, H = 540;
function xy(lon, lat) {
  return [((lon + 180) / 360) * W, ((90 - lat) / 180) * H];
}
function path(parts) {
  return parts.map((part) => "M" + part.map(([lon, lat]) => xy(lon, lat).map((v) => v.toFixed(1)).join(",")).join("L")).join("");
}
let coast = null;
async function coastlines() {
  if (coast === null) {
    const r = await fetch("coastlines.json");
    coast = r.ok ? await r.json() : [];
    if (!r.ok) fail(`coastlines.json: ${r.status}`);
  }
  return coast;
}
function mapSvg(geo, coastLines) {
  const by = Object.fromEntries(geo.features.map((f) => [f.properties.kind, f]));
  let grid = "";
  for (let lon = -180; lon <= 180; lon += 30) grid += `<path d="M${xy(lon, 90)}L${xy(lon, -90)}"/>`;
  for (let lat = -90; lat <= 90; lat += 30) grid += `<path d="M${xy(-180, lat)}L${xy(180, lat)}"/>`;
  let labels = "";
  for (let lon = -150; lon <= 150; lon += 60) labels += `<text x="${xy(lon, 0)[0] + 3}" y="${H - 6}">${lon}°</text>`;
  for (let lat = -60; lat <= 60; lat += 30) labels += `<text x="4" y="${xy(0, lat)[1] - 3}">${lat}°</text>`;
  const line = (kind, color, width, dash) => by[kind] ?
    `<path class="${kind}" d="${path(by[kind].geometry.coordinates)}" fill="none" stroke="${color}" stroke-width="${width}"${dash ? ` stroke-dasharray="${dash}"` : ""}/>` : "";
  // The night side at the chosen moment (a polygon, cut at the antimeridian by the service), shaded.
  let night = "";
  if (by.night) {
    const g = by.night.geometry;
    const rings = g.type === "Polygon" ? g.coordinates : g.coordinates.flat();
    night = `<path class="night" d="${rings.map((r) => path([r]) + "Z").join("")}" fill="#14213d" fill-opacity="0.16" fill-rule="evenodd"/>`;
  }
  const st = by.station.geometry.coordinates;
  const [sx, sy] = xy(st[0], st[1]);
  let access = "";
  if (by.t_access) {
    const [ax, ay] = xy(...by.t_access.geometry.coordinates);
    access = `<path d="M${ax},${ay - 9}L${ax + 3},${ay - 3}L${ax + 9},${ay - 3}L${ax + 4},${ay + 2}L${ax + 6},${ay + 9}L${ax},${ay + 5}L${ax - 6},${ay + 9}L${ax - 4},${ay + 2}L${ax - 9},${ay - 3}L${ax - 3},${ay - 3}Z" fill="#111"/>`;
  }
  return `<svg class="map" id="map" viewBox="0 0 ${W} ${H}" role="img" aria-label="ground tracks">
    ${night}
    <g stroke="#b7c8da" stroke-width="0.8">${grid}</g>
    <path class="coast" d="${path(coastLines)}" fill="none" stroke="#5d6d7e" stroke-width="0.7"/>
    <g fill="#6a7c90" font-size="11">${labels}</g>
    ${line("visibility_circle", "#c0392b", 1.6, "5 3")}
    ${line("observer_track", "#8e44ad", 1.2, "2 3")}
    ${line("target_track", "#7f8c8d", 1.4)}
    ${line("target_in_view", "#0b5cad", 3.5)}
    <path d="M${sx},${sy - 8}L${sx + 7},${sy + 5}L${sx - 7},${sy + 5}Z" fill="#c0392b" stroke="#fff"/>
    ${access}</svg>
    <div class="legend"><span><i class="sw-target"></i>target ground track</span>
    <span><i class="sw-inview"></i>target in view of the station</span>
    <span><i class="sw-observer"></i>observer ground track</span>
    <span><i class="sw-station"></i>station and where it sees the target (its mask, at ${num(by.visibility_circle.properties.height_km, 0)} km)</span>
    <span>★ target at T_access</span>${by.night ? `<span><i class="sw-night"></i>night at ${utc(by.night.properties.time)}</span>` : ""}</div>`;
}

// The radar's sky over the pass nearest the chosen moment: zenith at the centre, the horizon at the rim, north up
// and east to the right (as GNSS sky plots draw it); the station's mask shaded.
function skySvg(geo, station, tAccess) {
  const inview = geo.features.find((f) => f.properties.kind === "target_in_view");
  const sky = inview && inview.properties.sky_time_az_el_deg;
  if (!sky || !sky.length) return "";
  const S = 320, C = S / 2, Rr = C - 24;
  const at = (az, el) => {
    const r = Rr * (90 - Math.max(0, el)) / 90, a = (az * Math.PI) / 180;
    return [C + r * Math.sin(a), C - r * Math.cos(a)];
  };
  let g = "";
  for (const el of [0, 30, 60]) g += `<circle cx="${C}" cy="${C}" r="${Rr * (90 - el) / 90}" class="skyring"/><text x="${C + 3}" y="${C - Rr * (90 - el) / 90 + 12}" class="tick">${el}°</text>`;
  for (const [label, az] of [["N", 0], ["E", 90], ["S", 180], ["W", 270]]) {
    const [x, y] = at(az, -8);
    g += `<text x="${x}" y="${y + 4}" class="tick" text-anchor="middle">${label}</text>`;
  }
  const mask = (station && station.mask) || [];
  if (mask.length) {  // the mask, linear between its points and around north
    const pts = [];
    for (let az = 0; az <= 360; az += 5) {
      const m = maskAt(mask, az);
      pts.push(at(az, Math.max(m, station.min_elevation_deg || 0)));
    }
    g += `<path class="skymask" d="M${pts.map((p) => p.map((v) => v.toFixed(1)).join(",")).join("L")}Z M${C - Rr},${C}a${Rr},${Rr} 0 1,0 ${2 * Rr},0a${Rr},${Rr} 0 1,0 ${-2 * Rr},0Z" fill-rule="evenodd"/>`;
  }
  const track = sky.map(([, az, el]) => at(az, el).map((v) => v.toFixed(1)).join(",")).join("L");
  const [x0, y0] = at(sky[0][1], sky[0][2]);
  g += `<path class="skytrack" d="M${track}"/><circle cx="${x0}" cy="${y0}" r="4" class="skystart"><title>rise ${utc(sky[0][0])}</title></circle>`;
  // the time every 2 minutes along the arc (HH:MM UTC), and T_access as a star
  const times = sky.map(([t]) => Date.parse(t));
  for (let m = Math.ceil(times[0] / 120000) * 120000; m <= times[times.length - 1]; m += 120000) {
    const k = times.findIndex((t) => t >= m);
    const [x, y] = at(sky[k][1], sky[k][2]);
    g += `<circle cx="${x.toFixed(1)}" cy="${y.toFixed(1)}" r="2" class="skystart"/><text x="${(x + 5).toFixed(1)}" y="${(y - 4).toFixed(1)}" class="tick">${new Date(m).toISOString().slice(11, 16)}</text>`;
  }
  if (tAccess) {
    const ta = Date.parse(tAccess);
    const k = times.reduce((best, t, i) => (Math.abs(t - ta) < Math.abs(times[best] - ta) ? i : best), 0);
    const [x, y] = at(sky[k][1], sky[k][2]);
    g += `<text x="${x.toFixed(1)}" y="${(y + 6).toFixed(1)}" class="skyaccess" text-anchor="middle">★<title>T_access ${utc(tAccess)}</title></text>`;
  }
  const top = sky.reduce((a, b) => (b[2] > a[2] ? b : a));
  return `<div class="card sky"><b>The pass in the radar's sky</b> <span class="muted">(from ${utc(sky[0][0])}; highest ${num(top[2], 1)}° at azimuth ${num(top[1], 1)}°; the dot is where it rises, ★ T_access, times UTC)</span>
    <svg id="sky" viewBox="0 0 ${S} ${S}" role="img" aria-label="sky plot">${g}</svg></div>`;
}
function maskAt(mask, az) {
  const pts = mask.map(([a, e]) => [a, e]).sort((p, q) => p[0] - q[0]);
  if (pts.length === 1) return pts[0][1];
  const ext = [[pts[pts.length - 1][0] - 360, pts[pts.length - 1][1]], ...pts, [pts[0][0] + 360, pts[0][1]]];
  for (let k = 0; k < ext.length - 1; k++) {
    const [a0, e0] = ext[k], [a1, e1] = ext[k + 1];
    if (a0 <= az && az <= a1) return e0 + ((e1 - e0) * (az - a0)) / (a1 - a0 || 1);
  }
  return pts[0][1];
}

async function planPage(id) {
  const p = await api(`/v1/plans/${encodeURIComponent(id)}`);
  view.innerHTML = `<h1>Plan ${esc(p.target_name)} / ${esc(p.observer_name)} / ${esc(p.station_name)}</h1><p class="muted">Loading the pass...</p>`;
  const geo = await api(`/v1/plans/${encodeURIComponent(id)}/export/geojson`);
  const coastLines = await coastlines();
  const ch = p.chosen;
  const f = ch ? ch.feasibility : null;
  const verdict = !ch ? `<p class="verdict bad">No candidate was planned: ${esc((p.notes || []).join("; "))}</p>`
    : f.feasible ? `<p class="verdict good">Feasible: the target is sunlit at T_access and every check of the encounter passes.</p>`
      : `<p class="verdict bad">Not feasible: ${esc(f.reasons.join("; "))}.</p>`;
  const inChosen = (w) => ch && new Date(w.rise) <= new Date(ch.t_access) && new Date(ch.t_access) <= new Date(w.set);
  const windows = p.access_windows.map((w, k) => `<tr${inChosen(w) ? ' class="chosen"' : ""}>
      <td class="num">${k}</td><td>${utc(w.rise)}</td><td>${utc(w.culmination)}</td><td>${utc(w.set)}</td>
      <td class="num">${num(w.rise_azimuth_deg, 1)}</td><td class="num">${num(w.culmination_azimuth_deg, 1)}</td>
      <td class="num">${num(w.set_azimuth_deg, 1)}</td>
      <td class="num">${num(w.max_elevation_deg, 2)}</td><td class="num">${num(w.min_range_km, 1)}</td>
      <td class="num">${num(w.duration_s, 1)}</td><td>${w.keyhole ? "keyhole" : ""}</td></tr>`).join("");
  const ph = p.phasing;
  const scene = ch ? `<div class="grid">
      <div class="card"><b>Chosen scene</b><br>T_access ${utc(ch.t_access)}<br>height change dHa ${num(ch.delta_ha_km, 1)} km,
        dHp ${num(ch.delta_hp_km, 1)} km<br>node-line miss ${num(ch.miss_km, 3)} km (${esc(ch.node)})<br>
        target ${f.sunlit ? "sunlit" : "in Earth's shadow"}${ch.standoff_km == null ? "" : `<br>observer aimed
        ${num(ch.standoff_km, 1)} km beside it`}</div>
      ${f.radar_elevation_deg == null ? "" : `<div class="card"><b>Radar at T_access</b><br>elevation
        ${num(f.radar_elevation_deg, 1)} deg, range ${num(f.radar_range_km, 0)} km<br>the line of sight sweeps the
        frame's aperture in ${num(f.isar_integration_s, 1)} s${f.radar_snr_db == null ? "" : `<br>SNR
        ${num(f.radar_snr_db, 1)} dB over it (mean cross section ${num(f.radar_cross_section_m2, 1)} m²)`}</div>`}
      ${ph ? `<div class="card"><b>Phasing burn</b><br>${utc(ph.t_burn)} (${ph.revolutions_before} rev before)<br>
        dv ${num(ph.dv_total_m_s, 1)} m/s, RTN [${ph.dv_rtn_m_s.map((v) => num(v, 1)).join(", ")}] m/s<br>
        verified (numerical J2): ${num(ph.verification.miss_km * 1000, 1)} m from the aim point<br>
        closest approach ${num(ph.verification.closest_approach_km, 3)} km; the target crosses the observer's sky at
        ${num(ph.verification.target_angular_rate_deg_s, 2)} deg/s</div>` : ""}
    </div>` : "";
  const network = p.candidates.some((c) => c.station);
  const candidates = p.candidates.map((c, k) => {
    const cf = c.feasibility;
    const isChosen = ch && c.t_access === ch.t_access;
    return `<tr${isChosen ? ' class="chosen"' : ""}><td class="num">${k}</td><td>${utc(c.t_access)}</td>
      <td class="num">${num(c.delta_ha_km, 1)}</td><td class="num">${num(c.delta_hp_km, 1)}</td>
      <td class="num">${num(c.miss_km, 3)}</td><td class="num">${c.dv_total_m_s == null ? "-" : num(c.dv_total_m_s, 1)}</td>
      <td class="num">${c.standoff_km == null ? "-" : num(c.standoff_km, 1)}</td>
      <td class="num">${cf.target_angular_rate_deg_s == null ? "-" : num(cf.target_angular_rate_deg_s, 2)}</td>
      <td>${cf.sunlit ? "yes" : "no"}</td>${network ? `<td>${esc(c.station || "")}</td>` : ""}
      <td class="num">${cf.radar_elevation_deg == null ? "-" : num(cf.radar_elevation_deg, 1)}</td>
      <td class="num">${cf.radar_snr_db == null ? "-" : num(cf.radar_snr_db, 1)}</td>
      <td class="num">${cf.isar_integration_s == null ? "-" : num(cf.isar_integration_s, 1)}</td>
      <td class="reasons">${cf.feasible ? "yes" : `no: ${esc(cf.reasons.join("; "))}`}</td></tr>`;
  }).join("");
  const exportsList = ["opm", "opm?format=xml", "oem", "oem?format=xml", "czml", "geojson", "access.csv", "pointing.csv"]
    .map((k) => `<a href="#" data-export="${k}">${k.replace("?format=xml", " (XML)")}</a>`).join(" · ");
  view.innerHTML = `<h1>Plan ${esc(p.target_name)} / ${esc(p.observer_name)} / ${esc(p.station_name)}</h1>
    <p class="muted">${esc(p.id)} · created ${utc(p.created_at)} · ${p.duration_days} days from ${utc(p.epoch)} · elements ${esc(p.reading)}</p>
    ${verdict}${(p.notes || []).map((n) => `<p class="muted">note: ${esc(n)}</p>`).join("")}${mapSvg(geo, coastLines)}${skySvg(geo, (geo.features.find((x) => x.properties.kind === "station") || {}).properties, ch && ch.t_access)}${scene}${encounterCard(ph && ph.verification)}
    <h2>Access windows (${p.access_windows.length}, every one; the chosen pass highlighted)</h2>
    <div class="scroll"><table id="windows"><thead><tr><th class="num">#</th><th>rise (UTC)</th><th>culmination (UTC)</th><th>set (UTC)</th>
    <th class="num">az rise (deg)</th><th class="num">az culm. (deg)</th><th class="num">az set (deg)</th>
    <th class="num">max el (deg)</th><th class="num">min range (km)</th><th class="num">duration (s)</th><th></th></tr></thead>
    <tbody>${windows}</tbody></table></div>
    <h2>Candidates (${p.candidates.length}, every one; the chosen one highlighted)</h2>
    <table id="candidates"><thead><tr><th class="num">#</th><th>T_access (UTC)</th><th class="num">dHa (km)</th>
    <th class="num">dHp (km)</th><th class="num">miss (km)</th><th class="num">dv (m/s)</th><th class="num">stand-off (km)</th>
    <th class="num">rate (deg/s)</th><th>sunlit</th>${network ? "<th>radar</th>" : ""}<th class="num">radar el (deg)</th><th class="num">SNR (dB)</th>
    <th class="num">T_int (s)</th><th>feasible</th></tr></thead><tbody>${candidates ||
      '<tr><td colspan="13" class="muted">No pass has an alignment inside the box.</td></tr>'}</tbody></table>
    <h2>Exports</h2><p>${exportsList} <span id="exporting" class="muted"></span></p>
    <h2>Frames of this plan</h2>
    <p id="planwork">${(p.pass_ids || []).map((x) => `<a href="#/passes/${esc(x)}">pass ${esc(x.slice(0, 8))}</a>`).join(" · ") || "no pass"};
    ${(p.estimate_ids || []).map((x) => `<a href="#/estimates/${esc(x)}">estimate ${esc(x.slice(0, 8))}</a>`).join(" · ") || "no estimate"}</p>`;
  view.querySelectorAll("[data-export]").forEach((a) => a.addEventListener("click", async (ev) => {
    ev.preventDefault();
    const kind = a.dataset.export;
    const note = document.getElementById("exporting");
    note.textContent = `preparing ${kind} (a plan made before exports were stored is recomputed: a few seconds)...`;
    try {
      const blob = await api(`/v1/plans/${encodeURIComponent(id)}/export/${kind}`, "blob");
      const link = document.createElement("a");
      link.href = URL.createObjectURL(blob);
      link.download = `plan-${id}.${kind.replace("?format=xml", ".xml")}`;
      link.click();
      note.textContent = `${kind} ready`;
    } catch (err) {
      note.textContent = "";
      fail(err.message);
    }
  }));
}

// ---- campaigns
async function campaignsPage() {
  const body = await api("/v1/campaigns?limit=50");
  const rows = body.data.map((c) => `<tr>
      <td><a href="#/campaigns/${esc(c.id)}">${esc(c.id.slice(0, 8))}</a></td><td>${utc(c.created_at)}</td>
      <td>${esc(c.target_name)}</td><td>${esc(c.observer_name)}</td><td>${esc(c.station_name)}</td>
      <td class="num">${c.scenes}</td><td class="num">${num(c.dv_total_m_s, 1)}</td><td>${utc(c.first_access)}</td></tr>`).join("");
  view.innerHTML = `<h1>Campaigns <span class="muted">(${body.count})</span> <a class="action" href="#/new-campaign">New campaign</a></h1>
    <table id="campaigns"><thead><tr><th>campaign</th><th>created (UTC)</th><th>target</th><th>observer</th><th>station</th>
    <th class="num">scenes</th><th class="num">dv (m/s)</th><th>first T_access (UTC)</th></tr></thead><tbody>${rows ||
      '<tr><td colspan="8" class="muted">No campaigns yet: POST /v1/campaigns, or gsa campaign --server.</td></tr>'}</tbody></table>`;
}

// The campaign's delta-v as it is spent (the cumulative sum of its burns over time) against its budget, as
// `gsa campaign --plot` draws it: each scene's T_access a tick along the top with its number.
function dvChart(c) {
  const Wc = 760, Hc = 230, L = 58, R = 16, T = 22, B = 36;
  const t0 = Date.parse(c.epoch), span = c.duration_days * 86400e3;
  const X = (iso) => L + ((Date.parse(iso) - t0) / span) * (Wc - L - R);
  const burns = c.scenes.flatMap((s) => s.burns).sort((a, b) => Date.parse(a.time) - Date.parse(b.time));
  const top = Math.max(c.dv_budget_m_s, c.dv_total_m_s, 1) * 1.08;
  const Y = (v) => Hc - B - (v / top) * (Hc - T - B);
  let sum = 0, d = `M${L},${Y(0).toFixed(1)}`;
  for (const b of burns) {
    const x = X(b.time).toFixed(1);
    d += `L${x},${Y(sum).toFixed(1)}`;
    sum += b.dv_total_m_s;
    d += `L${x},${Y(sum).toFixed(1)}`;
  }
  d += `L${Wc - R},${Y(sum).toFixed(1)}`;
  let g = `<rect x="${L}" y="${T}" width="${Wc - L - R}" height="${Hc - T - B}" class="plotbg"/>`;
  for (let k = 0; k <= 4; k++) {
    const v = (top * k) / 4;
    g += `<line x1="${L}" x2="${Wc - R}" y1="${Y(v).toFixed(1)}" y2="${Y(v).toFixed(1)}" class="gridline"/><text x="${L - 6}" y="${(Y(v) + 4).toFixed(1)}" text-anchor="end" class="tick">${num(v, 0)}</text>`;
  }
  const days = Math.max(1, Math.round(c.duration_days / 6));
  for (let day = 0; day <= c.duration_days + 1e-9; day += days) {
    const x = L + (day / c.duration_days) * (Wc - L - R);
    g += `<text x="${x.toFixed(1)}" y="${Hc - B + 16}" text-anchor="middle" class="tick">${day}</text>`;
  }
  g += `<line x1="${L}" x2="${Wc - R}" y1="${Y(c.dv_budget_m_s).toFixed(1)}" y2="${Y(c.dv_budget_m_s).toFixed(1)}" class="budget"/>`;
  if (c.trim_margin_m_s) {
    const m = c.dv_budget_m_s - c.trim_margin_m_s;
    g += `<line x1="${L}" x2="${Wc - R}" y1="${Y(m).toFixed(1)}" y2="${Y(m).toFixed(1)}" class="budget margin"/>`;
  }
  g += `<path d="${d}" class="dvline" fill="none"/>`;
  for (const s of c.scenes) {
    const x = X(s.t_access).toFixed(1);
    g += `<line x1="${x}" x2="${x}" y1="${T}" y2="${T + 8}" class="scenetick"/><text x="${x}" y="${T - 5}" text-anchor="middle" class="tick">${s.index}<title>scene ${s.index}: T_access ${utc(s.t_access)}</title></text>`;
  }
  g += `<text x="${(L + Wc - R) / 2}" y="${Hc - 4}" text-anchor="middle" class="axisname">days from ${utc(c.epoch)}</text>`;
  g += `<text x="14" y="${(T + Hc - B) / 2}" text-anchor="middle" class="axisname" transform="rotate(-90 14 ${(T + Hc - B) / 2})">delta-v spent (m/s)</text>`;
  return `<svg class="panel dvchart" id="dvchart" viewBox="0 0 ${Wc} ${Hc}" role="img" aria-label="delta-v against the budget">${g}</svg>
    <div class="legend"><span><i class="sw-dv"></i>delta-v spent, burn by burn (${num(c.dv_total_m_s, 1)} m/s)</span>
    <span><i class="sw-budget"></i>budget ${num(c.dv_budget_m_s, 0)} m/s</span>${c.trim_margin_m_s ? `<span><i class="sw-margin"></i>less the trims' margin</span>` : ""}
    <span>ticks along the top: each scene's T_access</span></div>`;
}

async function campaignPage(id) {
  const c = await api(`/v1/campaigns/${encodeURIComponent(id)}`);
  const scenes = c.scenes.map((s) => {
    const f = s.candidate.feasibility;
    const burns = s.burns.map((b) => `${esc(b.kind)} ${utc(b.time)} ${num(b.dv_total_m_s, 1)} m/s`).join("<br>");
    return `<tr><td class="num">${s.index}</td><td>${utc(s.t_access)}</td><td class="num">${num(s.dv_total_m_s, 1)}</td>
      <td class="num">${num(s.candidate.standoff_km, 1)}</td><td class="num">${num(s.check.separation_km, 2)}</td>
      <td class="num">${num(s.check.target_angular_rate_deg_s, 2)}</td><td class="num">${num(s.check.phase_angle_deg, 1)}</td>
      <td>${(f.line_of_sight_rtn || []).map((v) => num(v, 2)).join(", ")}</td>
      <td class="num">${s.aim ? num(s.aim.tolerance_km, 2) : "-"}${s.reaimed ? " (re-aimed)" : ""}</td>
      <td>${s.candidate.station ? esc(s.candidate.station) : "-"}</td>
      <td>${s.dispersion ? `${num(100 * s.dispersion.feasible_share, 0)} % feasible, trims p95
        ${num(s.dispersion.trim_p95_m_s || 0, 1)} m/s` : "-"}</td>
      <td class="reasons">${burns}</td></tr>`;
  }).join("");
  const origin = c.replanned_from ? `<p>Re-planned from campaign <a href="#/campaigns/${esc(c.replanned_from)}">${esc(
    c.replanned_from.slice(0, 8))}</a> at ${utc(c.epoch)}: its later scenes re-aimed from the observer's measured state.</p>` : "";
  const stretches = c.stretches.map((st) => `<tr${st.scene === null ? "" : ' class="chosen"'}><td>${utc(st.start)}</td>
      <td>${utc(st.end)}</td><td class="num">${st.candidates}</td><td class="num">${st.feasible}</td>
      <td class="reasons">${esc(st.note)}</td></tr>`).join("");
  const exportsList = ["opm", "opm?format=xml", "oem", "oem?format=xml", "czml", "access.csv", "geojson", "pointing.csv",
    ...c.scenes.map((sc) => `pointing.csv?scene=${sc.index}`)]
    .map((k) => `<a href="#" data-export="${k}">${k.replace("?format=xml", " (XML)").replace("?scene=", " of scene ")}</a>`).join(" · ");
  const margin = c.trim_margin_m_s == null ? "" : `, ${num(c.trim_margin_m_s, 1)} m/s kept for the trims`;
  const verdict = c.scenes.length
    ? `<p class="verdict good">${c.scenes.length} feasible scene(s) for ${num(c.dv_total_m_s, 1)} of ${num(c.dv_budget_m_s, 0)} m/s${margin}.</p>`
    : `<p class="verdict bad">No feasible scene within the budget in the span: each stretch below says why.</p>`;
  view.innerHTML = `<h1>Campaign ${esc(c.target_name)} / ${esc(c.observer_name)} / ${esc(c.station_name)}</h1>
    <p class="muted">${esc(c.id)} · created ${utc(c.created_at)} · ${num(c.duration_days, 1)} days from ${utc(c.epoch)} ·
    return to orbit: ${c.return_to_orbit ? "yes" : "no"}</p>${verdict}${origin}
    ${(c.notes || []).map((n) => `<p class="muted">note: ${esc(n)}</p>`).join("")}
    ${c.scenes.length ? `<h2>Delta-v against the budget</h2>${dvChart(c)}` : ""}
    <h2>Scenes (measured on the whole flown burn sequence)</h2>
    <div class="scroll"><table id="scenes"><thead><tr><th class="num">#</th><th>T_access (UTC)</th><th class="num">dv (m/s)</th>
    <th class="num">stand-off (km)</th><th class="num">separation (km)</th><th class="num">rate (deg/s)</th>
    <th class="num">phase (deg)</th><th>line of sight (R, T, N)</th><th class="num">aim within (km)</th><th>radar</th>
    <th>with errors</th><th>burns</th></tr>
    </thead><tbody>${scenes || '<tr><td colspan="12" class="muted">None.</td></tr>'}</tbody></table></div>
    ${c.scenes.length ? `<h2>The fly-by of scene <select id="flyscene">${c.scenes.map((sc) => `<option value="${sc.index}">${sc.index}
      (${utc(sc.t_access)})</option>`).join("")}</select></h2><div id="flyby">${encounterCard(c.scenes[0].check, "as flown, in the target's orbital frame")}</div>` : ""}
    <h2>Stretches searched</h2>
    <table id="stretches"><thead><tr><th>from (UTC)</th><th>to (UTC)</th><th class="num">candidates</th>
    <th class="num">feasible</th><th>what came of it</th></tr></thead><tbody>${stretches}</tbody></table>
    <h2>Exports</h2><p>${exportsList}</p>`;
  const pick = document.getElementById("flyscene");
  if (pick) pick.addEventListener("change", () => {
    const sc = c.scenes.find((x) => String(x.index) === pick.value);
    document.getElementById("flyby").innerHTML = encounterCard(sc.check, "as flown, in the target's orbital frame");
  });
  view.querySelectorAll("[data-export]").forEach((a) => a.addEventListener("click", async (ev) => {
    ev.preventDefault();
    const kind = a.dataset.export;
    const blob = await api(`/v1/campaigns/${encodeURIComponent(id)}/export/${kind}`, "blob");
    const link = document.createElement("a");
    link.href = URL.createObjectURL(blob);
    link.download = `campaign-${id}.${kind.replace("?format=xml", ".xml").replace("?scene=", "-scene-")}`;
    link.click();
  }));
}

// ---- estimates
function euler(att) {
  return att ? att.euler_zyx_deg.map((v) => num(v, 2)).join(", ") : "-";
}
async function estimatesPage() {
  const body = await api("/v1/estimates?limit=50");
  const rows = body.data.map((e) => `<tr><td><a href="#/estimates/${esc(e.id)}">${esc(e.id.slice(0, 8))}</a></td>
      <td>${utc(e.created_at)}</td><td>${esc(e.input_name)}</td><td>${euler(e.attitude)}</td>
      <td>${e.quality ? (e.quality.trusted ? "yes" : "no") : "-"}</td>
      <td>${e.plan_id ? `<a href="#/plans/${esc(e.plan_id)}">${esc(e.plan_id.slice(0, 8))}</a>` : "-"}</td></tr>`).join("");
  const upload = await estimateForm();
  view.innerHTML = `<h1>Estimates <span class="muted">(${body.count})</span></h1>
    ${upload}
    <table id="estimates"><thead><tr><th>estimate</th><th>created (UTC)</th><th>input</th><th>z, y, x (deg)</th>
    <th>trusted</th><th>plan</th></tr></thead><tbody>${rows ||
      '<tr><td colspan="6" class="muted">No estimates yet: upload a frame above, POST /v1/estimates, or gsa estimate --server.</td></tr>'}</tbody></table>`;
  wireEstimateForm();
}

async function estimatePage(id) {
  const e = await api(`/v1/estimates/${encodeURIComponent(id)}`);
  const q = e.quality;
  // The 90 % bound is stated on the fitted answer's Euler angles (its frame's and, as one rotation, the others').
  const bound = q ? q.uncertainty_deg.map((v) => (v === null ? "-" : num(v, 2))).join(" / ") : "-";
  const frames = [["attitude", "observation frame (fitted)", true], ["attitude_network", "observation frame (Swin alone)", false],
    ["attitude_lvlh", "LVLH (the target's orbital frame)", true], ["attitude_j2000", "J2000", true]]
    .filter(([k]) => e[k]).map(([k, name, fitted]) => `<tr><td>${name}</td><td>${euler(e[k])}</td>
      <td>${fitted ? bound : "-"}</td><td>${e[k].quaternion_wxyz.map((v) => num(v, 5)).join(", ")}</td></tr>`).join("");
  const cells = e.model_cells_m;
  const scale = cells ? `1 pixel = ${num(cells[0], 3)} m in range (down) x ${num(cells[1], 3)} m in cross-range (across)` : "scale not kept for this estimate";
  const sent = e.cells_m ? `; sent with cells ${num(e.cells_m[0], 3)} x ${num(e.cells_m[1], 3)} m and resampled` : "";
  const snr = e.snr_db === null || e.snr_db === undefined ? "SNR not given" : `SNR ${num(e.snr_db, 1)} dB`;
  const verdict = !q ? "" : q.trusted
    ? `<p class="verdict good">Trusted${e.refined_on === "image" ? " (refined on the image)" : ""}: silhouette IoU ${num(q.silhouette_iou, 3)}, 90 % bound z / y / x ${q.uncertainty_deg.map((v) => num(v, 2)).join(" / ")} deg.</p>`
    : `<p class="verdict bad">Not trusted: ${esc(q.reasons.join("; "))}.</p>`;
  const onImage = e.refined_on === "image" && e.likelihood;
  const alts = (e.alternatives || []).map((a) => `<li>${euler(a)} deg (IoU ${num(a.silhouette_iou, 3)}, ${num(a.distance_deg, 1)} deg away${a.fitted === false ? ", the answer's near-mirror, unrefined" : ""})</li>`).join("");
  view.innerHTML = `<h1>Estimate ${esc(e.input_name)}</h1>
    <p class="muted">${esc(e.id)} · created ${utc(e.created_at)} · target ${esc(e.target || "-")} · frame ${e.shape.join(" x ")} · ${snr}
    ${e.plan_id ? ` · plan <a href="#/plans/${esc(e.plan_id)}">${esc(e.plan_id.slice(0, 8))}</a> observed ${utc(e.observed_at)}` : ""}</p>
    ${verdict}
    <p id="scale" class="muted">Frames as the models read them: ${scale}${sent}; the bar is 10 m.</p>
    <div class="grid frames"><div class="card"><b>Original frame</b> <span class="muted">with the fitted outline</span>
    <canvas id="overlay" class="frame"></canvas><img id="original" alt="original frame" hidden></div>
    <div class="card"><b>Enhanced by UNet++</b><img id="enhanced" alt="enhanced frame"></div>
    ${onImage ? `<div class="card"><b>The map's prediction</b> <span class="muted">at the answer</span><img id="map" alt="the reflectivity map's prediction"></div>
    <div class="card"><b>Frame over prediction</b> <span class="muted">dB: black -10, grey 0, white +10</span><img id="residual" alt="the frame over the map's prediction"></div>` : ""}</div>
    ${onImage ? `<p class="muted">Refined on the image: ${num(e.likelihood.nll_per_pixel, 4)} negative log-likelihood per pixel under the model set's reflectivity map; deviance ${num(e.likelihood.deviance, 3)} (its held-out labelled frames at most ${num(e.likelihood.deviance_max, 3)}).</p>` : ""}
    <h2>Attitude in each frame</h2>
    <table id="attitudes"><thead><tr><th>frame</th><th>Euler z, y, x (deg)</th><th>90 % bound z / y / x (deg)</th><th>quaternion w, x, y, z</th></tr></thead><tbody>${frames}</tbody></table>
    ${alts ? `<h2>Attitudes that fit nearly as well</h2><ul>${alts}</ul>` : ""}`;
  for (const which of ["original", "enhanced", ...(onImage ? ["map", "residual"] : [])]) {
    const blob = await api(`/v1/estimates/${encodeURIComponent(id)}/${which}.png`, "blob");
    document.getElementById(which).src = URL.createObjectURL(blob);
  }
  // The fitted outline (the target's projection at the answer) in orange over the original frame.
  const [frame, edge] = await Promise.all(["original", "outline"].map(async (which) => {
    const img = new Image();
    img.src = URL.createObjectURL(await api(`/v1/estimates/${encodeURIComponent(id)}/${which}.png`, "blob"));
    await img.decode();
    return img;
  }));
  const canvas = document.getElementById("overlay");
  canvas.width = frame.width;
  canvas.height = frame.height;
  const ctx = canvas.getContext("2d");
  ctx.drawImage(frame, 0, 0);
  const scratch = document.createElement("canvas");
  scratch.width = edge.width;
  scratch.height = edge.height;
  const sctx = scratch.getContext("2d");
  sctx.drawImage(edge, 0, 0);
  const picture = ctx.getImageData(0, 0, canvas.width, canvas.height);
  const mask = sctx.getImageData(0, 0, edge.width, edge.height).data;
  for (let i = 0; i < mask.length; i += 4) {
    if (mask[i] > 127) picture.data.set([255, 127, 14, 255], i);
  }
  ctx.putImageData(picture, 0, 0);
  if (cells) {  // a 10-m bar across (cross-range), bottom left
    const px = 10 / cells[1];
    ctx.fillStyle = "#000";  // a dark edge, so the bar shows on bright frames too
    ctx.fillRect(3, canvas.height - 10, px + 2, 10);
    ctx.fillStyle = "#fff";
    ctx.fillRect(4, canvas.height - 6, px, 2);
    ctx.fillRect(4, canvas.height - 9, 1, 8);
    ctx.fillRect(4 + px - 1, canvas.height - 9, 1, 8);
  }
  canvas.dataset.drawn = "1";
}

async function passesPage() {
  const body = await api("/v1/passes?limit=50");
  const rows = body.data.map((p) => `<tr><td><a href="#/passes/${esc(p.id)}">${esc(p.id.slice(0, 8))}</a></td>
      <td>${utc(p.created_at)}</td><td>${esc(p.target)}</td><td class="num">${p.used} / ${p.frames}</td>
      <td>${p.trusted ? "yes" : "no"}</td><td>${p.stable === null ? "-" : p.stable ? "still" : "turning"}</td>
      <td>${p.plan_id ? `<a href="#/plans/${esc(p.plan_id)}">${esc(p.plan_id.slice(0, 8))}</a>` : "-"}</td></tr>`).join("");
  view.innerHTML = `<h1>Passes <span class="muted">(${body.count})</span></h1>
    <table id="passes"><thead><tr><th>pass</th><th>created (UTC)</th><th>target</th><th class="num">frames used</th>
    <th>trusted</th><th>attitude</th><th>plan</th></tr></thead><tbody>${rows ||
      '<tr><td colspan="7" class="muted">No passes yet: POST /v1/passes, or gsa pass --server.</td></tr>'}</tbody></table>`;
}

let jobsTimer = null;

// Long work (/v1/jobs): each job's state, progress with counts and the time left, its result, its log's last lines;
// a queued or running job can be cancelled. The list looks again every 2 s while any job is active.
async function jobsPage() {
  const body = await api("/v1/jobs?limit=50");
  const active = body.data.some((j) => j.state === "queued" || j.state === "running");
  const link = (j) => j.result_url && j.result_url.startsWith("/v1/campaigns/")
    ? `<a href="#/campaigns/${esc(j.result_url.split("/").pop())}">campaign</a>`
    : j.result_url && j.kind === "dataset"
      ? `<a href="#/jobs" class="manifest" data-id="${esc(j.id)}">manifest</a>`
      : j.result_url ? `<code>${esc(j.result_url)}</code>` : "-";
  const rows = body.data.map((j) => `<tr class="job ${esc(j.state)}">
      <td><code>${esc(j.id.slice(0, 8))}</code></td><td>${esc(j.kind)}</td><td>${esc(j.state)}${j.cancel_requested ? " (cancelling)" : ""}</td>
      <td><progress max="1" value="${Number(j.progress)}"></progress> ${num(100 * j.progress, 0)} %${j.total ? ` · ${j.done}/${j.total}` : ""}${j.eta_s !== null ? ` · ${num(j.eta_s, 0)} s left` : ""}</td>
      <td>${esc(j.stage)}${j.error ? `<br><span class="bad">${esc(j.error)}</span>` : ""}</td><td>${utc(j.created_at)}</td>
      <td>${link(j)}</td>
      <td>${j.state === "queued" || j.state === "running" ? `<button class="cancel" data-id="${esc(j.id)}">Cancel</button>` : ""}
      ${j.log_tail ? `<details><summary>log</summary><pre>${esc(j.log_tail.split("\n").slice(-8).join("\n"))}</pre></details>` : ""}</td></tr>`).join("");
  view.innerHTML = `<h1>Jobs <span class="muted">(${body.count})</span></h1>
    <p class="muted">Adaptations, data sets and campaigns asked for with <code>Prefer: respond-async</code> run as jobs beside
    the service (<code>gsa jobs list|show|cancel|wait</code>).${active ? " Updating every 2 s while one is active." : ""}</p>
    <table id="jobs"><thead><tr><th>job</th><th>kind</th><th>state</th><th>progress</th><th>stage</th><th>created (UTC)</th>
    <th>result</th><th></th></tr></thead><tbody>${rows ||
      '<tr><td colspan="8" class="muted">No jobs yet: POST /v1/datasets, /v1/model-sets/{target}/adaptations, or a campaign with Prefer: respond-async.</td></tr>'}</tbody></table>
    <div id="manifest"></div>`;
  view.querySelectorAll("a.manifest").forEach((a) => a.addEventListener("click", async (ev) => {
    ev.preventDefault();
    const box = document.getElementById("manifest");
    box.innerHTML = "<p>Loading the manifest...</p>";
    try {
      const m = await api(`/v1/datasets/${encodeURIComponent(a.dataset.id)}/files/manifest.json`);
      box.innerHTML = `<h2>Data set ${esc(a.dataset.id.slice(0, 8))}</h2><p>${m.frames} frames in ${m.shards.length} shards
        (<code>GET /v1/datasets/${esc(a.dataset.id)}/files/shard-NNNNN.npz</code>), made on ${esc(m.engine || "local")}
        at ${num(m.frames_per_s, 1)} frames/s; content sha256 <code>${esc(m.content_sha256)}</code></p>`;
    } catch (err) { box.innerHTML = ""; fail(err.message); }
  }));
  view.querySelectorAll("button.cancel").forEach((b) => b.addEventListener("click", async () => {
    b.disabled = true;
    b.textContent = "Cancelling...";
    try { await api(`/v1/jobs/${encodeURIComponent(b.dataset.id)}`, "json", "DELETE"); } catch (err) { fail(err.message); }
    route();
  }));
  clearTimeout(jobsTimer);
  if (active) jobsTimer = setTimeout(() => { if (location.hash.startsWith("#/jobs")) route(); }, 2000);
}

// Continuous through +-180 deg about a reference value.
function near(v, ref) {
  return ref + ((((v - ref + 180) % 360) + 360) % 360) - 180;
}

// One SVG panel: each frame's angle on one axis over the pass with its 90 % bound, rejected frames (clipped to
// the panel), and the fused answer with its bound where the attitude held still.
function passPanel(p, axis, name) {
  const W = 1100, H = 190, L = 64, R = 16, T = 12, B = 28;
  const t0 = Date.parse(p.frames[0].observed_at);
  const ts = p.frames.map((f) => (Date.parse(f.observed_at) - t0) / 1000);
  const ref = p.attitude_lvlh.euler_zyx_deg[axis];
  const vals = p.frames.map((f) => near(f.attitude_lvlh.euler_zyx_deg[axis], ref));
  const bnd = p.frames.map((f) => f.quality.uncertainty_deg[axis]);
  const used = p.frames.map((f) => f.used);
  const keep = vals.filter((_, i) => used[i]);
  const span = keep.length ? keep : vals;
  const widest = Math.max(1, ...bnd.filter((b, i) => used[i] && b !== null && isFinite(b)).map((b) => 3 * b));
  const pad = Math.max(1, 0.5 * (Math.max(...span) - Math.min(...span)), widest);
  let lo = Math.min(...span) - pad, hi = Math.max(...span) + pad;
  if (p.stable) { lo = Math.min(lo, ref - 1.5 * p.uncertainty_deg[axis]); hi = Math.max(hi, ref + 1.5 * p.uncertainty_deg[axis]); }
  const tmax = Math.max(1, ...ts);
  const X = (t) => L + (t / tmax) * (W - L - R);
  const Y = (v) => T + (1 - (Math.min(hi, Math.max(lo, v)) - lo) / (hi - lo)) * (H - T - B);
  let g = `<rect x="${L}" y="${T}" width="${W - L - R}" height="${H - T - B}" class="plotbg"/>`;
  const ystep = niceStep(hi - lo);  // round ticks (encounter.js), and the times as UTC clock times
  for (let v = Math.ceil(lo / ystep) * ystep; v <= hi + 1e-9; v += ystep) {
    g += `<line x1="${L}" x2="${W - R}" y1="${Y(v)}" y2="${Y(v)}" class="gridline"/><text x="${L - 6}" y="${Y(v) + 4}" class="tick" text-anchor="end">${Number(v.toPrecision(6))}</text>`;
  }
  const tstep = niceStep(tmax);
  for (let t = 0; t <= tmax + 1e-9; t += tstep) {
    g += `<text x="${X(t)}" y="${H - 8}" class="tick" text-anchor="middle">${new Date(t0 + 1000 * t).toISOString().slice(11, 19)}Z</text>`;
  }
  if (p.stable) {
    const b = p.uncertainty_deg[axis];
    g += `<rect x="${L}" y="${Y(ref + b)}" width="${W - L - R}" height="${Y(ref - b) - Y(ref + b)}" class="fusedband"/>`;
    g += `<line x1="${L}" x2="${W - R}" y1="${Y(ref)}" y2="${Y(ref)}" class="fusedline"/>`;
  } else if (p.attitude_at) {
    const ta = (Date.parse(p.attitude_at) - t0) / 1000, b = p.uncertainty_deg[axis];
    g += `<line x1="${X(ta)}" x2="${X(ta)}" y1="${Y(ref - b)}" y2="${Y(ref + b)}" class="fusedline"/><circle cx="${X(ta)}" cy="${Y(ref)}" r="5" class="fusedpoint"/>`;
  }
  p.frames.forEach((f, i) => {
    const x = X(ts[i]), y = Y(vals[i]);
    if (used[i]) {
      const b = bnd[i];
      if (b !== null && isFinite(b)) g += `<line x1="${x}" x2="${x}" y1="${Y(vals[i] + b)}" y2="${Y(vals[i] - b)}" class="errbar"/>`;
      g += `<circle cx="${x}" cy="${y}" r="3.5" class="framepoint"><title>frame ${f.index}: ${num(vals[i], 2)} deg</title></circle>`;
    } else {
      g += `<path d="M${x - 4},${y - 4}L${x + 4},${y + 4}M${x - 4},${y + 4}L${x + 4},${y - 4}" class="rejected"><title>frame ${f.index} rejected: ${esc(f.rejected_because || "")}</title></path>`;
    }
  });
  g += `<text x="14" y="${T + (H - T - B) / 2}" class="axisname" transform="rotate(-90 14 ${T + (H - T - B) / 2})" text-anchor="middle">${name}</text>`;
  return `<svg class="panel" viewBox="0 0 ${W} ${H}" role="img" aria-label="${name} over the pass">${g}</svg>`;
}

async function passPage(id) {
  const p = await api(`/v1/passes/${encodeURIComponent(id)}`);
  const verdict = p.trusted
    ? `<p class="verdict good">Trusted: ${esc(p.stability)}.</p>`
    : `<p class="verdict bad">Not trusted: ${esc(p.stability)}.</p>`;
  const fused = p.attitude_lvlh.euler_zyx_deg.map((v, i) => `${num(v, 2)} &plusmn; ${num(p.uncertainty_deg[i], 2)}`).join(", ");
  const rows = p.frames.map((f) => `<tr class="${f.used ? "" : "rejectedrow"}"><td class="num">${f.index}</td>
      <td>${esc(f.name)}</td><td>${utc(f.observed_at)}</td><td>${euler(f.attitude_lvlh)}</td>
      <td>${f.quality.uncertainty_deg.map((v) => (v === null ? "-" : num(v, 2))).join(" / ")}</td>
      <td>${esc(f.branch)}</td><td class="num">${num(f.residual_deg, 2)}</td>
      <td class="reasons">${f.used ? "used" : "rejected: " + esc(f.rejected_because || "")}</td></tr>`).join("");
  view.innerHTML = `<h1>Pass ${esc(p.id.slice(0, 8))} <span class="muted">${esc(p.target)}</span></h1>
    <p class="muted">${esc(p.id)} · created ${utc(p.created_at)}
    ${p.plan_id ? ` · plan <a href="#/plans/${esc(p.plan_id)}">${esc(p.plan_id.slice(0, 8))}</a>` : ""}
    · ${p.used} frames used, ${p.rejected} rejected${p.attitude_at ? ` · attitude at ${utc(p.attitude_at)}` : ""}</p>
    ${verdict}
    <div class="card"><b>Fused attitude, body to LVLH</b> (Euler z, y, x with 90 % bounds, deg): ${fused}
    ${p.alternative_lvlh ? `<br><span class="muted">other branch as many frames agree with: ${euler(p.alternative_lvlh)} deg</span>` : ""}
    ${p.stable === false ? `<br>turning at ${p.rate_deg_s.map((v) => num(v, 3)).join(", ")} deg/s (body axes)` : ""}
    ${p.refined_on === "image" && p.likelihood ? `<br>refined on ${p.likelihood.frames} frames' images together under the model set's map: ${num(p.likelihood.moved_deg, 2)} deg from the silhouettes' answer (negative log-likelihood per pixel ${num(p.likelihood.start_nll_per_pixel, 4)} &rarr; ${num(p.likelihood.nll_per_pixel, 4)})` : ""}</div>
    <h2>Each frame's attitude over the pass</h2>
    <div class="legend"><span><i class="sw-frame"></i>frame, with its 90 % bound</span><span><i class="sw-rejected"></i>rejected (drawn at the edge when off scale)</span>
    <span><i class="sw-fused"></i>fused answer and its bound</span></div>
    <div id="panels">${[["z (yaw)", 0], ["y (pitch)", 1], ["x (roll)", 2]].map(([n, a]) => passPanel(p, a, n)).join("")}</div>
    <h2>Frames</h2>
    <div class="scroll"><table id="passframes"><thead><tr><th class="num">#</th><th>name</th><th>observed (UTC)</th><th>LVLH z, y, x (deg)</th>
    <th>90 % bound z / y / x</th><th>branch</th><th class="num">residual (deg)</th><th>verdict</th></tr></thead><tbody>${rows}</tbody></table></div>`;
}

// ---- model sets (issue 42): each target's versions, which one answers, promotion and rollback; the labelled frames
// the adaptations learn from, per scene, with where their attitudes lie in the networks' cube.
function labelledPanel(frames, a, b, names) {
  const S = 250, M = 34, lim = 60;
  const P = (v) => M + ((Math.max(-lim, Math.min(lim, v)) + lim) / (2 * lim)) * (S - 2 * M);
  const scenes = [...new Set(frames.map((f) => f.scene))];
  let g = `<rect x="${P(-45)}" y="${P(-45)}" width="${P(45) - P(-45)}" height="${P(45) - P(-45)}" class="plotbg"/>`;
  for (let v = -45; v <= 45; v += 15) {
    g += `<line x1="${P(v)}" x2="${P(v)}" y1="${P(-45)}" y2="${P(45)}" class="gridline"/><line y1="${P(-v)}" y2="${P(-v)}" x1="${P(-45)}" x2="${P(45)}" class="gridline"/>`;
  }
  g += `<text x="${S / 2}" y="${S - 6}" class="tick" text-anchor="middle">${names[0]} (deg, -45..45)</text>`;
  g += `<text x="10" y="${S / 2}" class="tick" text-anchor="middle" transform="rotate(-90 10 ${S / 2})">${names[1]} (deg)</text>`;
  frames.forEach((f) => {
    const hue = (scenes.indexOf(f.scene) * 137) % 360;
    g += `<circle cx="${P(f.angles_deg[a])}" cy="${P(-f.angles_deg[b])}" r="3" class="labelpoint" fill="hsl(${hue},65%,45%)"><title>${esc(f.name)} (${esc(f.scene)}): ${f.angles_deg.map((v) => num(v, 1)).join(", ")}</title></circle>`;
  });
  return `<svg class="coverage" viewBox="0 0 ${S} ${S}" role="img" aria-label="labelled attitudes, ${names[0]} against ${names[1]}">${g}</svg>`;
}

function figures(f) {
  if (!f) return "-";
  const parts = [];
  if (f.swin_geodesic_median_deg !== undefined) parts.push(`Swin median ${num(f.swin_geodesic_median_deg, 2)} deg`);
  if (f.iou_median !== undefined) parts.push(`UNet++ IoU ${num(f.iou_median, 3)}`);
  if (f.own_swin_geodesic_median_deg !== undefined) parts.push(`own frames ${num(f.own_swin_geodesic_median_deg, 2)} deg`);
  return parts.length ? esc(parts.join(", ")) : "-";
}

async function modelsPage() {
  const sets = await api("/v1/model-sets");
  const blocks = await Promise.all(sets.data.map(async (s) => {
    const lab = await api(`/v1/targets/${encodeURIComponent(s.target)}/labelled-frames?limit=100`);
    const own = s.answering_version !== s.shared_version;  // the caller promoted a version of its own
    const action = (v) => {
      if (v.version === s.answering_version) return "";
      const promote = v.version === 0
        ? (own ? `<button class="promote" data-target="${esc(s.target)}" data-version="0">Back to the shared default</button>` : "")
        : `<button class="promote" data-target="${esc(s.target)}" data-version="${v.version}">Promote for me</button>`;
      const remove = v.mine && !v.shared_default
        ? ` <button class="remove" data-target="${esc(s.target)}" data-version="${v.version}">Delete</button>` : "";
      return promote + remove;
    };
    const versions = s.versions.map((v) => `<tr class="${v.version === s.answering_version ? "answering" : ""}">
        <td class="num">${v.version}</td><td>${[v.version === s.answering_version ? "<b>answers you</b>" : "",
          v.shared_default ? "shared default" : "", v.mine ? "yours" : ""].filter(Boolean).join(", ")}</td>
        <td>${v.created_at ? utc(v.created_at) : "configured set"}</td><td class="num">${v.base_version ?? "-"}</td>
        <td class="num">${v.summary.labelled_frames ?? "-"}</td>
        <td>${v.summary.train_scenes ? esc(v.summary.train_scenes.length ?? v.summary.train_scenes) : "-"} / ${v.summary.validation_scenes ? esc(v.summary.validation_scenes.length ?? v.summary.validation_scenes) : "-"}</td>
        <td>${figures(v.summary.before)}</td><td>${figures(v.summary.after)}</td><td class="num">${num(v.summary.cpu_minutes, 1)}</td>
        <td>${action(v)}</td></tr>`).join("");
    const scenes = Object.entries(lab.per_scene).map(([k, n]) => `<tr><td>${esc(k)}</td><td class="num">${n}</td></tr>`).join("");
    const frames = lab.data.slice(0, 50).map((f) => `<tr><td>${esc(f.name)}</td><td>${esc(f.scene)}</td>
        <td>${f.angles_deg.map((v) => num(v, 2)).join(", ")}</td><td>${utc(f.observed_at)}</td><td>${esc(f.station_name || "-")}</td>
        <td class="num">${num(f.attitude_sigma_deg, 2)}</td><td class="num">${num(f.snr_db, 1)}</td><td>${utc(f.created_at)}</td></tr>`).join("");
    return `<section class="modelset"><h2>${esc(s.target)} <span class="muted">version ${s.answering_version} answers you;
      the shared default is ${s.shared_version}</span></h2>
      <table class="versions"><thead><tr><th class="num">version</th><th></th><th>made (UTC)</th><th class="num">from</th>
      <th class="num">labelled frames</th><th>scenes train / held out</th><th>held out, before</th><th>held out, after</th>
      <th class="num">CPU min</th><th></th></tr></thead><tbody>${versions}</tbody></table>
      <h3>Labelled frames <span class="muted">(${lab.count} in ${Object.keys(lab.per_scene).length} scene(s); ${num(100 * lab.coverage, 0)} % of the cube's 15 deg cells${lab.count > lab.data.length ? `; the newest ${lab.data.length} drawn` : ""})</span></h3>
      ${lab.count ? `<div class="coveragebox">${labelledPanel(lab.data, 0, 1, ["z", "y"])}${labelledPanel(lab.data, 0, 2, ["z", "x"])}
        <table class="scenes"><thead><tr><th>scene</th><th class="num">frames</th></tr></thead><tbody>${scenes}</tbody></table></div>
        <div class="scroll"><table class="labelled"><thead><tr><th>frame</th><th>scene</th><th>z, y, x (deg)</th><th>observed (UTC)</th>
        <th>station</th><th class="num">optical 1-sigma (deg)</th><th class="num">SNR (dB)</th><th>stored (UTC)</th></tr></thead><tbody>${frames}</tbody></table></div>`
        : `<p class="muted">None yet: add them below, POST /v1/targets/${esc(s.target)}/labelled-frames, or gsa labelled add DIR --target ${esc(s.target)} --server.</p>`}
      ${modelForms(s.target)}
      </section>`;
  }));
  view.innerHTML = `<h1>Model sets <span class="muted">(${sets.data.length})</span></h1>
    <p class="muted">Each adaptation (<code>POST /v1/model-sets/{target}/adaptations</code>, <code>gsa adapt</code>) is a new version
    of its target's set, learnt from your labelled frames below, and yours: promoting it changes what answers you alone. Everyone
    without a promotion of their own is answered by the shared default, which an admin key sets. Every estimate names its version.</p>
    ${blocks.join("") || '<p class="muted">No model sets: the service serves none.</p>'}`;
  wireModelForms();
  view.querySelectorAll("button.promote").forEach((b) => b.addEventListener("click", async () => {
    b.disabled = true;
    try {
      await api(`/v1/model-sets/${encodeURIComponent(b.dataset.target)}/versions/${b.dataset.version}/promote`, "json", "POST");
    } catch (err) { fail(err.message); }
    route();
  }));
  view.querySelectorAll("button.remove").forEach((b) => b.addEventListener("click", async () => {
    if (!confirm(`Delete version ${b.dataset.version} of ${b.dataset.target} and its files?`)) return;
    b.disabled = true;
    try {
      await api(`/v1/model-sets/${encodeURIComponent(b.dataset.target)}/versions/${b.dataset.version}`, "text", "DELETE");
    } catch (err) { fail(err.message); }
    route();
  }));
}

async function route() {
  takeKeyFromAddress();
  if (!key()) return askForKey();
  document.getElementById("who").innerHTML = `key ${esc(key().slice(0, 8))}... <button id="forget">Forget</button>`;
  document.getElementById("forget").addEventListener("click", () => { sessionStorage.removeItem("gsaKey"); route(); });
  const [where, query] = (location.hash.slice(1) || "/plans").split("?");
  const params = new URLSearchParams(query || "");
  const parts = where.split("/").filter(Boolean);
  view.innerHTML = "<p>Loading...</p>";
  try {
    if (parts[0] === "new-plan") await newScenePage("plan");
    else if (parts[0] === "new-campaign") await newScenePage("campaign");
    else if (parts[0] === "plans" && parts[1]) await planPage(decodeURIComponent(parts[1]));
    else if (parts[0] === "campaigns" && parts[1]) await campaignPage(decodeURIComponent(parts[1]));
    else if (parts[0] === "campaigns") await campaignsPage();
    else if (parts[0] === "estimates" && parts[1]) await estimatePage(decodeURIComponent(parts[1]));
    else if (parts[0] === "estimates") await estimatesPage();
    else if (parts[0] === "passes" && parts[1]) await passPage(decodeURIComponent(parts[1]));
    else if (parts[0] === "passes") await passesPage();
    else if (parts[0] === "jobs") await jobsPage();
    else if (parts[0] === "models") await modelsPage();
    else await plansPage(params);
  } catch (err) {
    if (!key()) return askForKey(err.message);  // a refused key: say so above the key form, not behind it
    fail(err.message);
  }
  settle();
}

window.addEventListener("hashchange", route);
window.addEventListener("error", (ev) => fail(`script error: ${ev.message}`));
route();
