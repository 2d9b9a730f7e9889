// swarmseek live map: server-sent events in, SVG drawn here (no library, no network beyond this server
// and an optional local tile server). Metres about the plan's origin: x east, y north, up in the side view.
"use strict";
(function () {
  const NS = "http://www.w3.org/2000/svg";
  const TRACK_DRAWN = 1500;
  const S = window.swarmseekMap = {config: null, state: null, tracks: {}, centre: [], events: [], lastSeq: 0,
    updates: 0, latencies_ms: [], arrivals: [], view: null, ended: false, connected: false};
  const $ = (id) => document.getElementById(id);

  function el(tag, attrs, parent) {
    const e = document.createElementNS(NS, tag);
    for (const k in attrs) e.setAttribute(k, attrs[k]);
    if (parent) parent.appendChild(e);
    return e;
  }
  function fmt(x, d) { return (x === null || x === undefined || !isFinite(x)) ? "-" : Number(x).toFixed(d); }
  function banner(id, text, cls) {
    const b = $(id);
    b.textContent = text || "";
    b.className = "banner " + (cls || "") + (text ? "" : " hidden");
  }

  // ------------------------------------------------------------------ geodesy (local, WGS-84 radii)
  function metresPerDeg(latDeg) {
    const p = latDeg * Math.PI / 180;
    return {lat: 111132.92 - 559.82 * Math.cos(2 * p) + 1.175 * Math.cos(4 * p),
            lon: 111412.84 * Math.cos(p) - 93.5 * Math.cos(3 * p)};
  }
  function origin() {
    const g = S.state && S.state.geometry;
    return g && g.origin ? g.origin : null;
  }

  // ------------------------------------------------------------------ view extent
  function points() {
    const pts = [];
    const g = S.state && S.state.geometry;
    if (g && g.fence_en_m && S.fitFence) for (const p of g.fence_en_m) pts.push([p[0], p[1]]);
    if (g && g.slots_enu) for (const k in g.slots_enu) pts.push(g.slots_enu[k]);
    if (S.state) for (const v of S.state.vehicles || []) if (v.position_enu) pts.push(v.position_enu);
    if (S.state && S.state.estimate_enu) pts.push(S.state.estimate_enu);
    if (S.config && S.config.truth_enu) pts.push(S.config.truth_enu);
    return pts;
  }
  function ensureView() {
    const pts = points();
    if (!pts.length) return false;
    const v = S.view;
    const margin = v ? v.span * 0.05 : 0;
    if (v && pts.every((p) => p[0] >= v.e0 + margin && p[0] <= v.e1 - margin && p[1] >= v.n0 + margin && p[1] <= v.n1 - margin)) return false;
    let e0 = Infinity, e1 = -Infinity, n0 = Infinity, n1 = -Infinity;
    for (const p of pts) { e0 = Math.min(e0, p[0]); e1 = Math.max(e1, p[0]); n0 = Math.min(n0, p[1]); n1 = Math.max(n1, p[1]); }
    const span = Math.max(e1 - e0, n1 - n0, 30) * (S.fitFence ? 1.1 : 1.6);
    const ce = (e0 + e1) / 2, cn = (n0 + n1) / 2;
    S.view = {e0: ce - span / 2, e1: ce + span / 2, n0: cn - span / 2, n1: cn + span / 2, span: span};
    layoutStatic();
    return true;
  }

  // ------------------------------------------------------------------ static layers (fence, band, grid, tiles)
  function layoutStatic() {
    const v = S.view, g = (S.state && S.state.geometry) || {};
    $("plan").setAttribute("viewBox", `${v.e0} ${-v.n1} ${v.span} ${v.span}`);
    const alts = ((S.state && S.state.vehicles) || []).map((x) => x.position_enu ? x.position_enu[2] : 0);
    if (S.config && S.config.truth_enu) alts.push(S.config.truth_enu[2]);
    const top = S.fitFence ? (g.max_alt_m || 0) * 1.08 + 2 : Math.max(...alts, 10) * 1.5 + 5;
    $("side").setAttribute("viewBox", `${v.e0} ${-top} ${v.span} ${top + 2}`);
    S.fontM = v.span / 55;
    const st = $("plan-static"); st.replaceChildren();
    if (g.fence_en_m && g.fence_en_m.length) {
      el("polygon", {class: "fence", points: g.fence_en_m.map((p) => `${p[0]},${-p[1]}`).join(" ")}, st);
    }
    const ss = $("side-static"); ss.replaceChildren();
    if (g.max_alt_m !== undefined) {
      el("rect", {class: "band", x: v.e0, width: v.span, y: -g.max_alt_m, height: g.max_alt_m - g.min_alt_m}, ss);
      el("line", {class: "grid", x1: v.e0, x2: v.e1, y1: 0, y2: 0}, ss);
      for (const a of [g.min_alt_m, g.max_alt_m]) {
        const t = el("text", {class: "gridlabel", x: v.e0 + S.fontM * 0.3, y: -a - S.fontM * 0.3, "font-size": S.fontM}, ss);
        t.textContent = `${fmt(a, 0)} m`;
      }
    }
    drawGrid(); drawTiles();
  }
  function star(x, y, r) {
    let d = "";
    for (let i = 0; i < 10; i++) {
      const a = Math.PI / 2 + i * Math.PI / 5, rr = i % 2 ? r * 0.45 : r;
      d += (i ? "L" : "M") + (x + rr * Math.cos(a)) + "," + (y - rr * Math.sin(a));
    }
    return d + "Z";
  }
  function gridStep(spanDeg) {
    const steps = [1e-5, 2e-5, 5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 1e-2, 2e-2, 5e-2, 0.1];
    for (const s of steps) if (spanDeg / s <= 7) return s;
    return 0.2;
  }
  function drawGrid() {
    const gg = $("plan-grid"); gg.replaceChildren();
    const o = origin(); if (!o) return;
    const v = S.view, m = metresPerDeg(o[0]), f = S.fontM;
    const step = gridStep(v.span / m.lat), dec = Math.max(0, Math.ceil(-Math.log10(step)));
    const lat0 = o[0] + v.n0 / m.lat, lat1 = o[0] + v.n1 / m.lat, lon0 = o[1] + v.e0 / m.lon, lon1 = o[1] + v.e1 / m.lon;
    for (let la = Math.ceil(lat0 / step) * step; la <= lat1; la += step) {
      const n = (la - o[0]) * m.lat;
      el("line", {class: "grid", x1: v.e0, x2: v.e1, y1: -n, y2: -n}, gg);
      el("text", {class: "gridlabel", x: v.e0 + f * 0.2, y: -n - f * 0.2, "font-size": f}, gg).textContent = `${la.toFixed(dec)}°`;
    }
    for (let lo = Math.ceil(lon0 / step) * step; lo <= lon1; lo += step) {
      const e = (lo - o[1]) * m.lon;
      el("line", {class: "grid", x1: e, x2: e, y1: -v.n1, y2: -v.n0}, gg);
      el("text", {class: "gridlabel", x: e + f * 0.2, y: -v.n0 - f * 0.3, "font-size": f}, gg).textContent = `${lo.toFixed(dec)}°`;
    }
  }
  function drawTiles() {
    const tg = $("plan-tiles"); tg.replaceChildren();
    const url = S.config && S.config.tile_url, o = origin();
    if (!url || !o) return;
    const v = S.view, m = metresPerDeg(o[0]);
    const px = $("plan").clientWidth || 800, mpp = v.span / px;
    const z = Math.max(0, Math.min(20, Math.round(Math.log2(156543.03 * Math.cos(o[0] * Math.PI / 180) / mpp))));
    const n2 = Math.pow(2, z);
    const tx = (lon) => (lon + 180) / 360 * n2;
    const ty = (lat) => { const r = lat * Math.PI / 180; return (1 - Math.log(Math.tan(r) + 1 / Math.cos(r)) / Math.PI) / 2 * n2; };
    const lon = (x) => x / n2 * 360 - 180;
    const lat = (y) => Math.atan(Math.sinh(Math.PI * (1 - 2 * y / n2))) * 180 / Math.PI;
    const x0 = Math.floor(tx(o[1] + v.e0 / m.lon)), x1 = Math.floor(tx(o[1] + v.e1 / m.lon));
    const y0 = Math.floor(ty(o[0] + v.n1 / m.lat)), y1 = Math.floor(ty(o[0] + v.n0 / m.lat));
    if ((x1 - x0 + 1) * (y1 - y0 + 1) > 100) return;
    for (let x = x0; x <= x1; x++) for (let y = y0; y <= y1; y++) {
      const e = (lon(x) - o[1]) * m.lon, w = (lon(x + 1) - o[1]) * m.lon - e;
      const nTop = (lat(y) - o[0]) * m.lat, nBot = (lat(y + 1) - o[0]) * m.lat;
      el("image", {href: url.replace("{z}", z).replace("{x}", x).replace("{y}", y), x: e, y: -nTop, width: w,
        height: nTop - nBot, preserveAspectRatio: "none"}, tg);
    }
  }

  // ------------------------------------------------------------------ dynamic layers
  function node(parent, id, tag, attrs) {
    let e = document.getElementById(id);
    if (!e) { e = el(tag, Object.assign({id: id}, attrs || {}), parent); }
    return e;
  }
  function drawTracks() {
    const tg = $("plan-tracks");
    for (const sysid in S.tracks) {
      const pts = S.tracks[sysid].slice(-TRACK_DRAWN);
      const v = (S.state.vehicles || []).find((x) => String(x.sysid) === sysid);
      const line = node(tg, `track-${sysid}`, "polyline", {});
      line.setAttribute("class", `track ${v ? v.flight_state : "landed"}`);
      line.setAttribute("points", pts.map((p) => `${p[0]},${-p[1]}`).join(" "));
    }
    node(tg, "centre-track", "polyline", {class: "centre-track"})
      .setAttribute("points", S.centre.slice(-TRACK_DRAWN).map((p) => `${p[0]},${-p[1]}`).join(" "));
  }
  function drawDynamic() {
    const st = S.state, v = S.view, r = v.span / 110, pd = $("plan-dyn"), sd = $("side-dyn");
    const slots = (st.geometry && st.geometry.slots_enu) || {};
    const seen = new Set();
    for (const sysid in slots) {
      const p = slots[sysid], id = `slot-${sysid}`; seen.add(id);
      const q = node(pd, id, "rect", {class: "slot"});
      q.setAttribute("x", p[0] - r * 0.8); q.setAttribute("y", -p[1] - r * 0.8);
      q.setAttribute("width", r * 1.6); q.setAttribute("height", r * 1.6);
    }
    for (const q of Array.from(pd.querySelectorAll(".slot"))) if (!seen.has(q.id)) q.remove();
    drawEstimate(pd, sd, st, r);
    if (S.config && S.config.truth_enu) {  // drawn above the estimate: the two meet at the end
      const t = S.config.truth_enu;
      node(pd, "truth", "path", {class: "truth"}).setAttribute("d", star(t[0], -t[1], r * 1.8));
      node(sd, "side-truth", "path", {class: "truth"}).setAttribute("d", star(t[0], -t[2], r * 1.8));
    }
    for (const veh of st.vehicles || []) {
      const p = veh.position_enu; if (!p) continue;
      const cls = `vehicle ${veh.flight_state || "landed"}`;
      const c = node(pd, `veh-${veh.sysid}`, "circle", {r: r});
      c.setAttribute("class", cls); c.setAttribute("cx", p[0]); c.setAttribute("cy", -p[1]); c.setAttribute("r", r);
      const t = node(pd, `vlabel-${veh.sysid}`, "text", {class: "vlabel"});
      t.textContent = veh.id; t.setAttribute("x", p[0] + r * 1.2); t.setAttribute("y", -p[1] - r); t.setAttribute("font-size", S.fontM * 0.8);
      const s = node(sd, `side-veh-${veh.sysid}`, "circle", {r: r});
      s.setAttribute("class", cls); s.setAttribute("cx", p[0]); s.setAttribute("cy", -p[2]); s.setAttribute("r", r);
    }
  }
  function drawPosterior(m) {
    const key = m ? JSON.stringify(m) : "";
    if (key === S.postKey) return;
    S.postKey = key;
    const g = $("plan-post"); g.replaceChildren();
    if (!m || !m.prob_e4 || !m.prob_e4.length) return;
    let top = 0;
    for (const row of m.prob_e4) for (const p of row) top = Math.max(top, p);
    if (!(top > 0)) return;
    m.prob_e4.forEach((row, i) => row.forEach((p, j) => {
      if (p <= 0) return;
      el("rect", {class: "post", x: m.east0_m + j * m.cell_m, y: -(m.north0_m + (i + 1) * m.cell_m), width: m.cell_m,
        height: m.cell_m, "fill-opacity": (0.7 * p / top).toFixed(3)}, g);
    }));
  }
  function drawEstimate(pd, sd, st, r) {
    drawPosterior(st.estimate_map);
    const e = st.estimate_enu, r95 = st.estimate_region95_m;
    const reg = node(pd, "estimate-region", "circle", {class: "est-region"});
    const sreg = node(sd, "side-estimate-region", "circle", {class: "est-region"});
    const mark = node(pd, "estimate", "path", {class: "est"});
    const smark = node(sd, "side-estimate", "path", {class: "est"});
    for (const x of [reg, sreg, mark, smark]) x.classList.toggle("hidden", !e);
    if (!e) return;
    const rr = (r95 !== null && r95 !== undefined && isFinite(r95)) ? r95 : 0;
    reg.setAttribute("cx", e[0]); reg.setAttribute("cy", -e[1]); reg.setAttribute("r", rr);
    sreg.setAttribute("cx", e[0]); sreg.setAttribute("cy", -e[2]); sreg.setAttribute("r", rr);
    reg.classList.toggle("hidden", !rr); sreg.classList.toggle("hidden", !rr);
    const k = r * 1.5;
    mark.setAttribute("d", `M${e[0] - k},${-e[1] - k}L${e[0] + k},${-e[1] + k}M${e[0] - k},${-e[1] + k}L${e[0] + k},${-e[1] - k}`);
    smark.setAttribute("d", `M${e[0] - k},${-e[2] - k}L${e[0] + k},${-e[2] + k}M${e[0] - k},${-e[2] + k}L${e[0] + k},${-e[2] - k}`);
  }

  // ------------------------------------------------------------------ table, header, events
  function drawTable() {
    const tb = document.querySelector("#vehicles tbody");
    for (const v of S.state.vehicles || []) {
      let row = document.getElementById(`row-${v.sysid}`);
      if (!row) { row = tb.insertRow(); row.id = `row-${v.sysid}`; for (let i = 0; i < 9; i++) row.insertCell(); }
      const cells = [v.id, v.flight_state || "", v.mode || "", v.armed === undefined ? "" : (v.armed ? "yes" : "no"),
        fmt(v.relative_alt_m, 1), fmt(v.battery_pct, 0), fmt(v.link_age_s, 2), fmt(v.setpoint_rate_hz, 1), v.status || ""];
      cells.forEach((c, i) => { if (row.cells[i].textContent !== String(c)) row.cells[i].textContent = c; });
      row.cells[1].className = v.flight_state || "";
    }
  }
  function addEvents(list) {
    const ol = $("events");
    for (const ev of list || []) {
      if (!(ev.seq > S.lastSeq)) continue;
      S.lastSeq = ev.seq; S.events.push(ev);
      const li = document.createElement("li");
      li.className = ev.type === "command" ? "command" : (ev.level || "");
      let text = ev.message || "";
      if (ev.type === "phase") text = `phase ${ev.phase}`;
      if (ev.type === "command") text = `command ${ev.command} from ${ev.sender}: ${ev.accepted ? "accepted" : "REJECTED"} (${ev.reason || ""})`;
      li.textContent = `[${fmt(ev.t_s - (S.t0 || ev.t_s), 1)} s] ${text}`;
      ol.insertBefore(li, ol.firstChild);
      while (ol.childElementCount > 300) ol.lastChild.remove();
    }
  }
  function drawHeader() {
    const st = S.state;
    if (S.t0 === undefined && st.t_s !== undefined) S.t0 = st.t_s - (st.elapsed_s || 0);
    $("phase").textContent = st.phase || "-";
    $("elapsed").textContent = fmt(st.elapsed_s, 1);
    $("iteration").textContent = st.iteration ?? "-";
    const e = st.estimate_enu;
    $("estimate-text").textContent = e ? `(${fmt(e[0], 1)}, ${fmt(e[1], 1)}, ${fmt(e[2], 1)}) m` +
      (st.estimate_region95_m ? `, r95 ${fmt(st.estimate_region95_m, 2)} m` : "") : "-";
    const end = st.ending;
    if (end || st.final || st.phase === "done") {
      S.ended = true;
      const what = end ? `${end.outcome}: ${end.message}` : `phase ${st.phase}`;
      banner("banner", `Mission ended — ${what}`, end && end.outcome === "converged" ? "ended" : "failed");
    } else if (st.control && st.control.paused) {
      banner("banner", `Paused by ${st.control.paused_by}`, "");
    } else if (S.connected) {
      banner("banner", "", "");
    }
  }
  function stats() {
    const now = performance.now();
    S.arrivals = S.arrivals.filter((t) => now - t < 5000);
    const span = S.arrivals.length > 1 ? (now - S.arrivals[0]) / 1000 : 0;
    $("rate").textContent = span > 0 ? ((S.arrivals.length - 1) / span).toFixed(1) : "0.0";
    const l = S.latencies_ms.slice(-200).sort((a, b) => a - b);
    $("latency").textContent = l.length ? l[Math.floor(l.length / 2)].toFixed(0) : "-";
  }

  // ------------------------------------------------------------------ the stream
  function onState(st, redraw) {
    S.state = st;
    if (!redraw) {
      S.updates += 1; S.arrivals.push(performance.now());
      if (st.published_wall_s) S.latencies_ms.push(Date.now() - st.published_wall_s * 1000);
    }
    if (S.latencies_ms.length > 5000) S.latencies_ms.splice(0, 1000);
    for (const v of st.vehicles || []) {
      if (!v.position_enu) continue;
      const t = S.tracks[v.sysid] || (S.tracks[v.sysid] = []), last = t[t.length - 1], p = v.position_enu;
      if (!last || Math.hypot(p[0] - last[0], p[1] - last[1], p[2] - last[2]) >= 0.2) t.push(p);
    }
    const c = st.centre_enu, lc = S.centre[S.centre.length - 1];
    if (c && (!lc || Math.hypot(c[0] - lc[0], c[1] - lc[1], c[2] - lc[2]) >= 0.2)) S.centre.push(c);
    if (!S.view || !S.geometryDrawn) { S.view = null; S.geometryDrawn = !!st.geometry; }
    ensureView();
    if (S.view) { drawTracks(); drawDynamic(); }
    drawHeader(); drawTable(); addEvents(st.events);
    if (S.replay && st.t_s !== undefined) { $("replay-slider").value = st.t_s - S.replay.t0_s; $("replay-time").textContent = fmt(st.t_s - S.replay.t0_s, 1); }
  }
  function onConfig(cfg) {
    S.config = cfg;
    $("fleet").textContent = cfg.fleet || "";
    const buttons = document.querySelectorAll("#commands button");
    buttons.forEach((b) => { b.disabled = !!cfg.read_only; });
    if (cfg.read_only) banner("readonly", `READ-ONLY — ${cfg.read_only_reason}`, "readonly");
    $("commands").classList.toggle("readonly", !!cfg.read_only);
    $("login").classList.toggle("hidden", !cfg.login);
    if (cfg.replay) {
      S.replay = cfg.replay;
      $("replay").classList.remove("hidden");
      $("replay-slider").max = cfg.replay.t1_s - cfg.replay.t0_s;
      $("replay-speed").value = String(cfg.replay.speed);
    }
    S.view = null;
  }
  function onHistory(h) {
    if (h.t0_s !== null && h.t0_s !== undefined) S.t0 = h.t0_s;
    S.tracks = {}; for (const k in h.tracks) S.tracks[k] = h.tracks[k];
    S.centre = h.centre_track || []; S.lastSeq = 0; $("events").replaceChildren();
    $("plan-tracks").replaceChildren();
    addEvents(h.events);
  }
  function connect() {
    const es = new EventSource("/events");
    es.addEventListener("open", () => { S.connected = true; if (!S.ended) banner("banner", "", ""); });
    es.addEventListener("config", (e) => onConfig(JSON.parse(e.data)));
    es.addEventListener("history", (e) => onHistory(JSON.parse(e.data)));
    es.addEventListener("state", (e) => onState(JSON.parse(e.data)));
    es.addEventListener("reset", () => { S.tracks = {}; S.centre = []; S.lastSeq = 0; $("events").replaceChildren(); $("plan-tracks").replaceChildren(); });
    es.addEventListener("source", (e) => { const d = JSON.parse(e.data); if (!S.ended) banner("banner", d.ok ? "" : d.message, d.ok ? "" : "failed"); });
    es.addEventListener("error", () => {
      S.connected = false;
      if (!S.ended) banner("banner", "connection to the map server lost; retrying", "failed");
      else $("banner").textContent = $("banner").textContent.replace(/ \(map server stopped\)$/, "") + " (map server stopped)";
    });
  }

  // ------------------------------------------------------------------ commands and replay controls
  async function post(url, body) {
    const r = await fetch(url, {method: "POST", headers: {"Content-Type": "application/json",
      "X-CSRF-Token": (S.config && S.config.csrf_token) || ""}, body: JSON.stringify(body), credentials: "same-origin"});
    let doc = {};
    try { doc = await r.json(); } catch (e) { doc = {accepted: false, reason: `HTTP ${r.status}`}; }
    return doc;
  }
  async function command(name) {
    if (S.config && S.config.read_only) return;
    if ((S.config.confirm || ["abort", "return", "land", "rtl"]).includes(name) && !window.confirm(`Send "${name}" to fleet ${S.config.fleet}? This ends the mission.`)) return;
    $("ack").textContent = `${name}: sending…`;
    const ack = await post("/api/command", {command: name});
    $("ack").textContent = `${name} ${ack.accepted ? "accepted" : "REJECTED"}${ack.phase ? ` (phase ${ack.phase})` : ""}: ${ack.reason || ""}`;
  }
  document.addEventListener("DOMContentLoaded", () => {
    document.querySelectorAll("#commands button").forEach((b) => b.addEventListener("click", () => command(b.dataset.command)));
    $("login").addEventListener("submit", async (e) => {
      e.preventDefault();
      const r = await post("/api/login", {password: $("password").value});
      $("ack").textContent = r.ok ? "logged in" : `login refused: ${r.reason}`;
      if (r.ok) $("login").classList.add("hidden");
    });
    $("replay-slider").addEventListener("change", () => post("/api/replay", {seek_s: Number($("replay-slider").value)}));
    $("replay-speed").addEventListener("change", () => post("/api/replay", {speed: Number($("replay-speed").value)}));
    $("replay-play").addEventListener("click", () => {
      const paused = $("replay-play").textContent === "Pause";
      $("replay-play").textContent = paused ? "Play" : "Pause";
      post("/api/replay", {paused: paused});
    });
    $("view-mode").addEventListener("change", () => { S.fitFence = $("view-mode").value === "fence"; S.view = null; if (S.state) onState(S.state, true); });
    setInterval(stats, 500);
    connect();
  });
})();
