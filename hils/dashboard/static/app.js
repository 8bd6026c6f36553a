// The dashboard page: draws a board snapshot (hils/dashboard/board.py, Board.snapshot), or for a run of
// several controllers one panel per intersection (Panels.snapshot), each drawn like the single board, compact.
// Live: snapshots arrive as server-sent events. Replay: the slider asks for the board at a sim time.
"use strict";

const $ = (id) => document.getElementById(id);
const NAMES = { G: "green", Y: "yellow", r: "red", F: "flashing yellow arrow" };
// "-": no verified signal state (polls failing, halted in TIMEOUT or by the close): hatched, never the last state.
const COLORS = { G: "#1fa64a", Y: "#f2c21b", r: "#c8322b", "-": "url(#no-data)" };
const HATCH = '<defs><pattern id="no-data" width="6" height="6" patternUnits="userSpaceOnUse" ' +
  'patternTransform="rotate(45)"><rect width="6" height="6" fill="#eceef1"/>' +
  '<line x1="0" y1="0" x2="0" y2="6" stroke="#9aa1ad" stroke-width="2"/></pattern></defs>';
const STATES = { idle: "IDLE", on_hold: "ON_HOLD", timeout: "TIMEOUT", preempted: "PREEMPTED", closed: "CLOSED" };
let meta = null;

// The run's secret, printed at start in the page's URL (?token=..., as Jupyter does): kept for this tab, taken out
// of the address bar (it is not for screenshots or links), and sent with the requests that control the run.
const token = (() => {
  const here = new URL(location.href);
  const given = here.searchParams.get("token");
  if (given) {
    sessionStorage.setItem("hils-token", given);
    here.searchParams.delete("token");
    history.replaceState(null, "", here.pathname + here.search + here.hash);
  }
  return sessionStorage.getItem("hils-token");
})();

function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) node.setAttribute(k, v);
  for (const c of children) node.append(c);
  return node;
}

function fmt(x, digits = 2) { return x === null || x === undefined ? "–" : Number(x).toFixed(digits); }

// A view is where one board is drawn: the single page's elements, or one panel's (compact).
function singleView() {
  return { compact: false, tls: null, rings: $("rings"), strip: $("strip"), state: $("state"), reason: $("reason"),
           recover: $("recover"), said: $("recover-said"), commands: $("commands").tBodies[0], comms: $("comms"),
           queues: $("queues") };
}

function panelView(p) {
  const v = { compact: true, tls: p.id };
  v.state = el("span", { class: "state", "data-testid": "manager-state" }, "–");
  v.reason = el("div", { class: "reason", "data-testid": "timeout-reason" });
  v.recover = el("button", { type: "button", class: "recover", "data-testid": "recover", hidden: "" }, "Recover");
  v.said = el("span", { class: "said" });
  v.rings = el("div", { class: "rings", "data-testid": "rings" });
  v.strip = document.createElementNS("http://www.w3.org/2000/svg", "svg");
  v.strip.setAttribute("class", "strip");
  v.strip.setAttribute("data-testid", "strip");
  v.commands = el("tbody");
  v.comms = el("dl", { class: "comms", "data-testid": "comms" });
  v.queues = el("div", { class: "queues" });
  const head = el("tr", {}, ...["phases", "at (s)", "verified", "hold", "outcome"].map((h) => el("th", {}, h)));
  v.root = el("article", { class: "card panel", "data-intersection": p.id,
                           style: `grid-column: ${p.col + 1}; grid-row: ${p.row + 1}` },
    el("div", { class: "panel-head" }, el("h3", {}, p.id), el("span", { class: "cfg" }, p.name), v.state),
    // The reason below the diagrams: the panels' diagrams stay aligned when one is in TIMEOUT.
    v.rings, v.strip,
    v.reason, el("div", { class: "recover-row" }, v.recover, v.said),
    el("table", { class: "commands" }, el("thead", {}, head), v.commands),
    v.comms, el("div", { class: "sub" }, "queued vehicles per approach"), v.queues);
  v.recover.onclick = () => recover(v);
  return v;
}

function shortWhat(p) {
  if (!p.approach) return p.turn || " ";
  return `${p.approach[0].toUpperCase()} ${p.turn === "through" ? "thru" : p.turn || ""}`;
}

function drawRings(v, snap) {
  const byPhase = new Map(snap.phases.map((p) => [p.phase, p]));
  const c = v.compact;
  // Polls failing, or halted in TIMEOUT: the indications are the last ones polled, not what the street shows.
  const stale = snap.state === "timeout" || snap.comms.failing > 0;
  v.rings.classList.toggle("stale", stale);
  v.rings.title = stale ? "as last polled: polling is failing or halted (TIMEOUT)" : "";
  v.rings.replaceChildren();
  snap.rings.forEach((ring, r) => {
    const row = el("div", { class: "ring" }, el("span", { class: "label" }, c ? `R${r + 1}` : `Ring ${r + 1}`));
    for (let b = 0; b < snap.barriers; b++) {
      const cell = el("div", { class: "barrier" });
      for (const n of ring) {
        const p = byPhase.get(n);
        if (p.barrier !== b) continue;
        const shown = p.shown || "none";
        const what = [p.approach, p.turn].filter(Boolean).join(" ");
        const box = el("div", { class: `phase ${shown}`, "data-phase": n, "data-shown": shown,
                                title: `phase ${n}${what ? " (" + what + ")" : ""}: ${NAMES[p.shown] || "not polled yet"}` },
          el("div", { class: "num" }, `Φ${n}`),
          el("div", { class: "what" }, c ? shortWhat(p) : what || " "));
        if (!c) box.append(el("div", { class: "what" }, NAMES[p.shown] || "not polled"));
        if (p.ped === "walk") box.append(el("span", { class: "chip walk", "data-ped": "walk" }, "WALK"));
        if (p.ped === "ped_clear") box.append(el("span", { class: "chip fdw", "data-ped": "ped_clear" }, "FDW"));
        if (p.next) box.append(el("span", { class: "chip next", "data-next": "1" }, "next"));
        if (p.call) box.append(el("span", { class: "chip call" }, "call"));
        if (p.ped_call) box.append(el("span", { class: "chip call" }, c ? "ped" : "ped call"));
        if (p.vehcall) box.append(el("span", { class: "chip set" }, c ? "SET" : "VehCall SET"));
        cell.append(box);
      }
      row.append(cell);
    }
    v.rings.append(row);
  });
  if (snap.overlaps.length) v.rings.append(overlapRow(snap, c));
}

// The overlaps as the controller showed them at its last cabinet read (a flashing yellow arrow blinks).
function overlapRow(snap, c) {
  const row = el("div", { class: "ring overlaps" }, el("span", { class: "label" }, c ? "OL" : "Overlaps"));
  for (const o of snap.overlaps) {
    const shown = o.shown || "none";
    const parents = o.included.join("+") + (o.modifiers.length ? ` ${o.type === "fya" ? "~" : "−"}${o.modifiers.join("+")}` : "");
    const what = [o.approach, o.turn].filter(Boolean).join(" ");
    const box = el("div", { class: `phase ${shown}`, "data-overlap": o.letter, "data-shown": shown,
                            title: `overlap ${o.letter} (${o.type}, included ${o.included.join(", ")}` +
                                   (o.modifiers.length ? `, modifiers ${o.modifiers.join(", ")}` : "") +
                                   `): ${NAMES[o.shown] || "not read yet"}` },
      el("div", { class: "num" }, `OL ${o.letter}`),
      el("div", { class: "what" }, c ? parents : `${parents}${what ? " · " + what : ""}`));
    if (!c) box.append(el("div", { class: "what" }, NAMES[o.shown] || "not read"));
    row.append(box);
  }
  return row;
}

function cabinetNote(snap) {
  return snap.cabinet_read
    ? "WALK, FDW (flashing don't walk), calls, next (PhaseNext) and overlaps as the controller showed them at its last read (every 1 s)."
    : "Walks, calls and PhaseNext were not read in this run (they are read during dashboard runs).";
}

function drawStrip(v, snap) {
  const svg = v.strip, c = v.compact;
  const phases = snap.phases.map((p) => p.phase);
  const width = svg.clientWidth || 600, rowH = c ? 10 : 22, left = c ? 24 : 34, top = 4, font = c ? 9 : 12;
  const bar = c ? rowH - 2 : rowH - 6, pad = c ? 1 : 2, base = c ? 8 : 15;
  const height = top + rowH * phases.length + (c ? 14 : 18);
  svg.setAttribute("height", height);
  svg.setAttribute("viewBox", `0 0 ${width} ${height}`);
  const w = snap.strip.window_s, t1 = snap.t, t0 = t1 - w;
  const x = (t) => left + ((Math.max(t, t0) - t0) / w) * (width - left - 6);
  const parts = [HATCH];
  const segs = snap.strip.segments;
  phases.forEach((n, i) => {
    const y = top + i * rowH;
    parts.push(`<text x="2" y="${y + base}" font-size="${font}" fill="#6b7280">Φ${n}</text>`);
    parts.push(`<rect x="${left}" y="${y + pad}" width="${width - left - 6}" height="${bar}" fill="#eceef1"/>`);
    // One bar per run of the same indication: segments change when any phase changes.
    let runStart = null, runShown = null;
    const flush = (end) => {
      if (runStart === null || end < t0) return;
      parts.push(`<rect x="${x(runStart)}" y="${y + pad}" width="${Math.max(0, x(end) - x(runStart))}" ` +
                 `height="${bar}" fill="${COLORS[runShown]}" shape-rendering="crispEdges"/>`);
    };
    segs.forEach(([start, shown]) => {
      const s = shown === null ? "-" : shown[String(n)] || "r";
      if (s === runShown) return;
      flush(start);
      runStart = start; runShown = s;
    });
    flush(t1);
  });
  // Each stretch without data says so once, across the rows, where it is wide enough to read.
  segs.forEach(([start, shown], k) => {
    const end = k + 1 < segs.length ? segs[k + 1][0] : t1;
    if (shown !== null || end < t0 || x(end) - x(start) < (c ? 34 : 48)) return;
    parts.push(`<text x="${(x(start) + x(end)) / 2}" y="${top + (rowH * phases.length) / 2 + 4}" ` +
               `font-size="${font}" fill="#1d2330" text-anchor="middle" data-testid="no-data">no data</text>`);
  });
  const axisY = top + rowH * phases.length + (c ? 10 : 12);
  for (let s = 0; s <= w; s += c ? 60 : 30) {
    const anchor = s === 0 ? "start" : s === w ? "end" : "middle";
    parts.push(`<text x="${x(t0 + s)}" y="${axisY}" font-size="${c ? 9 : 11}" fill="#6b7280" text-anchor="${anchor}">` +
               `${s === w ? "now" : "−" + (w - s) + " s"}</text>`);
  }
  svg.innerHTML = parts.join("");
}

function drawManager(v, snap) {
  v.state.textContent = STATES[snap.state] || snap.state;
  v.state.className = `state ${snap.state}`;
  v.state.dataset.state = snap.state;
  const to = snap.timeout;
  v.reason.textContent = to ? `reason: ${to.reason}${to.detail ? " — " + to.detail : ""}` +
                              (to.recovering ? " (recovering…)" : "") : "";
  v.recover.hidden = !(meta && meta.control && token && snap.state === "timeout" && !snap.ended);
}

function drawCommands(v, snap) {
  // A panel lists the last three, without the command's number.
  const rows = v.compact ? snap.commands.slice(0, 3) : snap.commands;
  v.commands.replaceChildren(...rows.map((c) => el("tr", {},
    ...(v.compact ? [] : [el("td", {}, String(c.id ?? "–"))]),
    el("td", {}, c.phases.join("+") + (c.green ? ` (${c.green}s)` : "")),
    el("td", {}, fmt(c.t, 1)), el("td", {}, fmt(c.verified_s)), el("td", {}, fmt(c.hold_s)),
    el("td", {}, c.outcome || "holding"))));
}

function drawComms(v, snap) {
  const c = snap.comms;
  const failed = c.polls_failed + (c.failing ? ` (${c.failing} in a row)` : "");
  const lag = c.last_lag_s === null ? "–" : `${fmt(c.last_lag_s, 3)} s`;
  const sets = `${c.sets.sent} / ${c.sets.answered} / ${c.sets.failed}`;
  const rows = v.compact
    ? [["polls ok / failed", `${c.polls_ok} / ${failed}`], ["verification lag", lag], ["SETs sent/ans./failed", sets]]
    : [["polls answered", c.polls_ok], ["polls failed", failed], ["last verification lag", lag],
       ["SETs sent / answered / failed", sets], ["actions dropped / refused", `${c.dropped} / ${c.refused}`],
       ["drifted steps", c.drifts]];
  v.comms.replaceChildren(...rows.flatMap(([k, val]) => [el("dt", {}, k), el("dd", {}, String(val))]));
}

function drawQueues(v, snap) {
  if (!snap.queues) {
    v.queues.replaceChildren(el("span", { class: "muted" }, v.compact ? "no queues (no traffic simulation, or no sample yet)"
      : "no traffic simulation in this run (or no sample yet)"));
    return;
  }
  // Panels share one scale, so that bars compare across the map.
  const max = v.queueScale || Math.max(1, ...Object.values(snap.queues));
  v.queues.replaceChildren(...Object.entries(snap.queues).map(([name, q]) => el("div", { class: "qrow" },
    el("span", {}, name), el("div", { class: "qbar", style: `width:${(100 * q) / max}%` }), el("span", {}, String(q)))));
}

function drawBoard(v, snap) {
  drawRings(v, snap); drawManager(v, snap); drawCommands(v, snap); drawComms(v, snap); drawQueues(v, snap); drawStrip(v, snap);
}

let single = null;
const panels = new Map();

function drawPanels(snap) {
  const root = $("panels");
  root.style.setProperty("--cols", snap.cols);
  const queueScale = Math.max(1, ...snap.panels.flatMap((p) => Object.values(p.queues || {})));
  for (const p of snap.panels) {
    let v = panels.get(p.id);
    if (!v) {
      v = panelView(p);
      panels.set(p.id, v);
      root.append(v.root);
    }
    v.queueScale = queueScale;
    drawBoard(v, { ...p, t: snap.t });
  }
  $("map-note").textContent = cabinetNote(snap.panels[0]);
}

function draw(snap) {
  const run = snap.run || {};
  const what = run.config || run.scenario;
  $("run").textContent = what ? `${what} · ${run.mode} · ${run.action_type} · agent ${run.agent}` : "waiting for the run…";
  $("clock").textContent = `t = ${fmt(snap.t, 1)} s`;
  let status = snap.ended ? `run ended: ${snap.ended}` : meta.mode === "live" ? "live" : "replay";
  document.body.dataset.t = snap.t;
  if (snap.panels) {
    $("map").hidden = false; $("single").hidden = true;
    drawPanels(snap);
    const timeouts = snap.panels.filter((p) => p.state === "timeout").map((p) => p.id);
    if (timeouts.length) status += ` · TIMEOUT at ${timeouts.join(", ")}`;
  } else {
    single = single || singleView();
    drawBoard(single, snap);
    $("cabinet-note").textContent = cabinetNote(snap);
  }
  $("status").textContent = status;
}

async function recover(v) {
  const res = await fetch("/api/recover" + (v.tls ? `?intersection=${encodeURIComponent(v.tls)}` : ""),
                          { method: "POST", headers: { "X-Hils-Token": token } });
  const said = await res.json();
  v.said.textContent = said.recover || `refused: ${said.error}`;
}

function live() {
  const source = new EventSource("/api/stream");
  source.onmessage = (ev) => {
    const snap = JSON.parse(ev.data);
    draw(snap);
    if (snap.ended) source.close();
  };
  source.onerror = () => { $("status").textContent = "disconnected (run over?)"; };
  $("recover").onclick = () => recover(singleView());
}

function replay() {
  $("replay").hidden = false;
  const slider = $("slider"), play = $("play"), speed = $("speed");
  slider.max = meta.end;
  const factor = String(meta.realtime);
  if (![...speed.options].some((o) => o.value === factor)) speed.append(el("option", { value: factor }, `${factor}×`));
  speed.value = factor;
  let busy = false, timer = null, last = 0;
  const show = async () => {
    if (busy) return;
    busy = true;
    try {
      const res = await fetch(`/api/snapshot?t=${slider.value}`);
      draw(await res.json());
      $("slider-t").textContent = `${fmt(slider.value, 1)} / ${fmt(meta.end, 0)} s`;
    } finally { busy = false; }
  };
  slider.oninput = show;
  play.onclick = () => {
    if (timer) { clearInterval(timer); timer = null; play.textContent = "Play"; return; }
    play.textContent = "Pause";
    last = performance.now();
    timer = setInterval(() => {
      const now = performance.now();
      const t = Math.min(meta.end, Number(slider.value) + ((now - last) / 1000) * Number(speed.value));
      slider.value = t;
      last = now;
      // Stop on the time asked for, not on the slider's value, which the browser may round.
      if (t >= meta.end) play.onclick();
      show();
    }, 200);
  };
  show();
}

(async () => {
  meta = await (await fetch("/api/meta")).json();
  if (meta.mode === "live") live(); else replay();
})();
