// GSA-ISAR console: the forms that make things (a plan, an estimate), over the same /v1 API and the same key as
// every page. The server checks everything; its 4xx message is shown at the field it names. Loaded before
// console.js, whose helpers (api, esc, view, settle, route) these functions use when they run.
"use strict";

// The paper's Table 1 scene (the API's own example), for a newcomer's first plan.
const PAPER = {
  target: { name: "Sat_Target", text: '{"epoch": "2022-11-27T16:00:00Z", "ha_km": 700, "hp_km": 600, "inclination_deg": 43,\n "raan_deg": 290, "arg_perigee_deg": 100, "mean_anomaly_deg": 200}' },
  observer: { name: "Sat_Obs", text: '{"epoch": "2022-11-27T16:00:00Z", "ha_km": 700, "hp_km": 350, "inclination_deg": 99,\n "raan_deg": 10, "arg_perigee_deg": 0, "mean_anomaly_deg": 316.5}' },
  station: { name: "GS", latitude_deg: "31.1", longitude_deg: "121.3", altitude_m: "0" },
};
const ORBIT_KINDS = [
  ["auto", "recognised from the text"], ["tle", "TLE or 3LE"], ["omm", "OMM JSON (CelesTrak)"], ["omm_xml", "OMM XML"],
  ["omm_kvn", "OMM KVN"], ["omm_csv", "OMM CSV"], ["opm", "OPM (KVN or XML)"], ["elements", "elements (JSON)"],
];

// Which of the API's orbit fields a pasted text goes in, and its value there; throws a message for the field.
function orbitSource(text, kind) {
  const t = text.trim();
  if (!t) throw new Error("paste the orbit: a TLE, an OMM (JSON, XML, KVN or CSV), an OPM, or elements as JSON");
  let k = kind;
  if (k === "auto") {
    if (t.startsWith("{") || t.startsWith("[")) {
      const v = parseJson(t);
      return [Array.isArray(v) || "OBJECT_NAME" in v || "MEAN_MOTION" in v ? "omm" : "elements", v];
    }
    if (/CCSDS_OPM_VERS|<opm\b/i.test(t)) k = "opm";
    else if (/CCSDS_OMM_VERS/.test(t)) k = "omm_kvn";
    else if (t.startsWith("<")) k = "omm_xml";
    else if (/^OBJECT_NAME,/.test(t)) k = "omm_csv";
    else k = "tle";
  }
  return [k, k === "omm" || k === "elements" ? parseJson(t) : t];
}
function parseJson(t) {
  try {
    return JSON.parse(t);
  } catch (err) {
    throw new Error(`not JSON: ${err.message}`);
  }
}

// POST (JSON or a FormData) as api() does, but hand back 4xx bodies instead of throwing: {status, body}.
async function send(path, body) {
  pending += 1;
  status.dataset.ready = "0";
  try {
    const json = !(body instanceof FormData);
    const headers = { "X-API-Key": key(), ...(json ? { "Content-Type": "application/json" } : {}) };
    const r = await fetch(path, { method: "POST", headers, body: json ? JSON.stringify(body) : body });
    let out = null;
    try { out = await r.json(); } catch (e) { out = { detail: r.statusText }; }
    return { status: r.status, body: out };
  } finally {
    pending -= 1;
    settle();
  }
}

// Put each error of a 4xx answer at the form's element whose data-loc is the longest prefix of the error's loc.
function showErrors(form, detail) {
  form.querySelectorAll(".fielderror").forEach((e) => e.remove());
  const errors = Array.isArray(detail) ? detail : [{ loc: [], msg: String(detail) }];
  for (const e of errors) {
    const path = (e.loc || []).filter((p) => p !== "body" && p !== "query" && typeof p === "string").join(".");
    let best = null;
    form.querySelectorAll("[data-loc]").forEach((el) => {
      const loc = el.dataset.loc;
      if ((path === loc || path.startsWith(loc + ".")) && (!best || loc.length > best.dataset.loc.length)) best = el;
    });
    const where = best || form;
    const shown = path && !best ? `${path}: ${e.msg}` : e.msg;
    // inside a fieldset or the form; right after a label (a paragraph inside one would break its line)
    const place = where.tagName === "LABEL" ? "afterend" : "beforeend";
    where.insertAdjacentHTML(place, `<p class="error fielderror" data-for="${esc(path)}">${esc(shown)}</p>`);
  }
}

function orbitFieldset(role, legend) {
  const kinds = ORBIT_KINDS.map(([v, t]) => `<option value="${v}">${esc(t)}</option>`).join("");
  return `<fieldset data-loc="${role}"><legend>${legend}</legend>
    <label>name <input type="text" name="${role}_name" required></label>
    <label>format <select name="${role}_kind">${kinds}</select></label>
    <textarea name="${role}_text" rows="4" spellcheck="false"
      placeholder="a TLE (2 lines, or 3 with a name), CelesTrak's OMM (JSON, XML, KVN, CSV), a CCSDS OPM, or elements as JSON"></textarea>
  </fieldset>`;
}

// A plan (POST /v1/plans) or a campaign (POST /v1/campaigns): both orbits, the radar, the span.
async function newScenePage(kind) {
  const campaign = kind === "campaign";
  const stations = await api("/v1/stations?limit=100");
  const stored = stations.data.map((s) => `<option value="${esc(s.name)}">${esc(s.name)} (stored)</option>`).join("");
  const span = campaign
    ? `<fieldset data-loc="campaign"><legend>Campaign</legend>
        <label data-loc="start">start (UTC, ISO 8601; empty: the target's epoch) <input type="text" name="start"></label>
        <label data-loc="duration_days">days <input type="text" name="duration_days" class="short" value="60"></label>
        <label data-loc="dv_budget_m_s">dv budget (m/s) <input type="text" name="dv_budget_m_s" class="short" value="1000"></label>
        <label data-loc="max_scenes">at most scenes <input type="text" name="max_scenes" class="short" value="20"></label>
      </fieldset>`
    : `<fieldset data-loc="search"><legend>Search</legend>
        <label data-loc="search.start">start (UTC, ISO 8601; empty: the target's epoch) <input type="text" name="start"></label>
        <label data-loc="search.duration_days">days <input type="text" name="duration_days" class="short" value="10"></label>
      </fieldset>`;
  view.innerHTML = `<h1>New ${kind}</h1>
    <p class="muted">${campaign
      ? "Paste both orbits, choose the radar, and plan a campaign: one GSA scene after another within the dv budget (<code>POST /v1/campaigns</code>; tens of seconds)."
      : "Paste both orbits, choose the radar, and plan: the scene, its phasing burn and the radar's view (<code>POST /v1/plans</code>)."}
    <button type="button" id="paper">Fill in the paper's Table 1 scene</button></p>
    <form id="planform" class="entry">
      <div class="grid">${orbitFieldset("target", "Target (imaged by the radar)")}${orbitFieldset("observer", "Observer (the optical satellite)")}</div>
      <fieldset data-loc="ground_station"><legend>Radar site</legend>
        <label>station <select name="station"><option value="">a new site:</option>${stored}</select></label>
        <span class="newsite">
          <label>name <input type="text" name="gs_name" class="short"></label>
          <label>latitude (deg) <input type="text" name="gs_lat" class="short"></label>
          <label>longitude (deg) <input type="text" name="gs_lon" class="short"></label>
          <label>altitude (m) <input type="text" name="gs_alt" class="short" value="0"></label>
        </span>
      </fieldset>
      ${span}
      <p><button id="plansubmit">Plan</button> <span id="planstate" class="muted"></span></p>
    </form>`;
  const form = document.getElementById("planform");
  const field = (name) => form.elements.namedItem(name);
  const number = (name) => (field(name).value.trim() === "" ? null : Number(field(name).value));
  document.getElementById("paper").addEventListener("click", () => {
    for (const role of ["target", "observer"]) {
      field(`${role}_name`).value = PAPER[role].name;
      field(`${role}_text`).value = PAPER[role].text;
    }
    field("station").value = "";
    field("gs_name").value = PAPER.station.name;
    field("gs_lat").value = PAPER.station.latitude_deg;
    field("gs_lon").value = PAPER.station.longitude_deg;
    field("gs_alt").value = PAPER.station.altitude_m;
    field("duration_days").value = campaign ? "60" : "30";
  });
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const body = {};
    const local = [];
    for (const role of ["target", "observer"]) {
      try {
        const [k, v] = orbitSource(field(`${role}_text`).value, field(`${role}_kind`).value);
        body[role] = { name: field(`${role}_name`).value.trim(), [k]: v };
      } catch (err) {
        local.push({ loc: [role], msg: err.message });
      }
    }
    body.ground_station = field("station").value || {
      name: field("gs_name").value.trim(), latitude_deg: number("gs_lat"), longitude_deg: number("gs_lon"), altitude_m: number("gs_alt") ?? 0,
    };
    const span = campaign ? body : (body.search = {});
    if (field("start").value.trim()) span.start = field("start").value.trim();
    for (const name of campaign ? ["duration_days", "dv_budget_m_s", "max_scenes"] : ["duration_days"]) {
      if (field(name).value.trim()) span[name] = number(name);
    }
    if (local.length) return showErrors(form, local);
    const button = document.getElementById("plansubmit");
    button.disabled = true;
    document.getElementById("planstate").textContent = campaign
      ? "planning the campaign (up to GSA_CAMPAIGN_TIMEOUT_S)..." : "planning (a few seconds; up to GSA_PLAN_TIMEOUT_S)...";
    const r = await send(campaign ? "/v1/campaigns" : "/v1/plans", body);
    button.disabled = false;
    document.getElementById("planstate").textContent = "";
    if (r.status === 201) location.hash = `#/${campaign ? "campaigns" : "plans"}/${encodeURIComponent(r.body.id)}`;
    else showErrors(form, r.body.detail ?? `${r.status}`);
  });
}

// The model sets page: labelled frames in, an adaptation started (a job: the Jobs page follows it).
function modelForms(target) {
  const t = esc(target);
  return `<form class="entry labelledform" data-target="${t}"><fieldset data-loc="files"><legend>Add labelled frames of ${t}</legend>
      <input type="file" name="files" multiple accept=".npz">
      <label data-loc="scene">scene of files that name none <input type="text" name="scene" class="short"></label>
      <button>Upload</button> <span class="state muted"></span></fieldset></form>
    <form class="entry adaptform" data-target="${t}"><fieldset data-loc="adapt"><legend>Adapt ${t}'s set to your frames</legend>
      <label data-loc="max_minutes">at most minutes <input type="text" name="max_minutes" class="short" value="10"></label>
      <label><input type="checkbox" name="map_only"> only the reflectivity map (a few CPU minutes)</label>
      <button>Adapt</button> <span class="state muted"></span></fieldset></form>`;
}

function wireModelForms() {
  document.querySelectorAll("form.labelledform").forEach((form) => form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const files = form.elements.namedItem("files").files;
    if (!files.length) return showErrors(form, [{ loc: ["files"], msg: "choose labelled frames: .npz files (inference.labelled's format)" }]);
    const data = new FormData();
    for (const f of files) data.append("files", f, f.name);
    const scene = form.elements.namedItem("scene").value.trim();
    if (scene) data.append("scene", scene);
    form.querySelector(".state").textContent = "uploading...";
    const r = await send(`/v1/targets/${encodeURIComponent(form.dataset.target)}/labelled-frames`, data);
    form.querySelector(".state").textContent = "";
    if (r.status === 201) route();
    else showErrors(form, r.body.detail ?? `${r.status}`);
  }));
  document.querySelectorAll("form.adaptform").forEach((form) => form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const body = {};
    const minutes = form.elements.namedItem("max_minutes").value.trim();
    if (minutes) body.max_minutes = Number(minutes);
    if (form.elements.namedItem("map_only").checked) body.map_only = true;
    const r = await send(`/v1/model-sets/${encodeURIComponent(form.dataset.target)}/adaptations`, body);
    if (r.status === 202) location.hash = "#/jobs";
    else showErrors(form, r.body.detail ?? `${r.status}`);
  }));
}

// The estimates page's upload: one frame in, its estimate's page out.
async function estimateForm() {
  const ready = await api("/readyz");
  const targets = (ready.targets || []).map((t) => `<option value="${esc(t)}">${esc(t)}</option>`).join("");
  return `<form id="estimateform" class="entry"><fieldset data-loc="file"><legend>Estimate a frame</legend>
    <input type="file" name="file" id="framefile" accept=".npy,.npz,.png,.tif,.tiff">
    <label data-loc="target">target <select name="target">${targets}</select></label>
    <label><input type="checkbox" name="normalised"> already the models' input (as <code>gsa simulate</code> writes)</label>
    <label><input type="checkbox" name="resample"> resample to the models' size in pixels (<code>resample=true</code>)</label>
    <button id="estimatesubmit">Estimate</button> <span id="estimatestate" class="muted"></span>
  </fieldset></form>`;
}

function wireEstimateForm() {
  const form = document.getElementById("estimateform");
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const file = form.elements.namedItem("file").files[0];
    if (!file) return showErrors(form, [{ loc: ["file"], msg: "choose a frame: .npy, .npz, PNG or TIFF" }]);
    const data = new FormData();
    data.append("file", file, file.name);
    data.append("target", form.elements.namedItem("target").value);
    if (form.elements.namedItem("normalised").checked) data.append("normalised", "true");
    if (form.elements.namedItem("resample").checked) data.append("resample", "true");
    document.getElementById("estimatestate").textContent = "estimating...";
    const r = await send("/v1/estimates", data);
    document.getElementById("estimatestate").textContent = "";
    if (r.status === 201) location.hash = `#/estimates/${encodeURIComponent(r.body.id)}`;
    else showErrors(form, r.body.detail ?? `${r.status}`);
  });
}
