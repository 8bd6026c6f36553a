// The dashboard page: draws a board snapshot (hils/dashboard/board.py, Board.snapshot).
// Live: snapshots arrive as server-sent events. Replay: the slider asks for the board at a sim time.
"use strict";

const $ = (id) => document.getElementById(id);
const NAMES = { G: "green", Y: "yellow", r: "red" };
const COLORS = { G: "#1fa64a", Y: "#f2c21b", r: "#c8322b" };
const STATES = { idle: "IDLE", on_hold: "ON_HOLD", timeout: "TIMEOUT", closed: "CLOSED" };
let meta = null;

function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) node.setAttribute(k, v);
  for (const c of children) node.append(c);
  return node;
}

function fmt(x, digits = 2) { return x === null || x === undefined ? "–" : Number(x).toFixed(digits); }

function drawRings(snap) {
  const byPhase = new Map(snap.phases.map((p) => [p.phase, p]));
  const root = $("rings");
  root.replaceChildren();
  snap.rings.forEach((ring, r) => {
    const row = el("div", { class: "ring" }, el("span", { class: "label" }, `Ring ${r + 1}`));
    for (let b = 0; b < snap.barriers; b++) {
      const cell = el("div", { class: "barrier" });
      for (const n of ring) {
        const p = byPhase.get(n);
        if (p.barrier !== b) continue;
        const shown = p.shown || "none";
        const box = el("div", { class: `phase ${shown}`, "data-phase": n, "data-shown": shown,
                                title: `phase ${n}: ${NAMES[p.shown] || "not polled yet"}` },
          el("div", { class: "num" }, `Φ${n}`),
          el("div", { class: "what" }, [p.approach, p.turn].filter(Boolean).join(" ") || " "),
          el("div", { class: "what" }, NAMES[p.shown] || "not polled"));
        if (p.ped === "walk") box.append(el("span", { class: "chip walk", "data-ped": "walk" }, "WALK"));
        if (p.ped === "ped_clear") box.append(el("span", { class: "chip fdw", "data-ped": "ped_clear" }, "FDW"));
        if (p.next) box.append(el("span", { class: "chip next", "data-next": "1" }, "next"));
        if (p.call) box.append(el("span", { class: "chip call" }, "call"));
        if (p.ped_call) box.append(el("span", { class: "chip call" }, "ped call"));
        if (p.vehcall) box.append(el("span", { class: "chip set" }, "VehCall SET"));
        cell.append(box);
      }
      row.append(cell);
    }
    root.append(row);
  });
}

function drawCabinetNote(snap) {
  $("cabinet-note").textContent = snap.cabinet_read
    ? "WALK, FDW (flashing don't walk), calls and next (PhaseNext) as the controller showed them at its last read (every 1 s)."
    : "Walks, calls and PhaseNext were not read in this run (they are read during dashboard runs).";
}

function drawStrip(snap) {
  const svg = $("strip");
  const phases = snap.phases.map((p) => p.phase);
  const width = svg.clientWidth || 600, rowH = 22, left = 34, top = 4;
  const height = top + rowH * phases.length + 18;
  svg.setAttribute("height", height);
  svg.setAttribute("viewBox", `0 0 ${width} ${height}`);
  const w = snap.strip.window_s, t1 = snap.t, t0 = t1 - w;
  const x = (t) => left + ((Math.max(t, t0) - t0) / w) * (width - left - 6);
  const ns = "http://www.w3.org/2000/svg";
  const parts = [];
  const segs = snap.strip.segments;
  phases.forEach((n, i) => {
    const y = top + i * rowH;
    parts.push(`<text x="2" y="${y + 15}" font-size="12" fill="#6b7280">Φ${n}</text>`);
    parts.push(`<rect x="${left}" y="${y + 2}" width="${width - left - 6}" height="${rowH - 6}" fill="#eceef1"/>`);
    // One bar per run of the same indication: segments change when any phase changes.
    let runStart = null, runShown = null;
    const flush = (end) => {
      if (runStart === null || end < t0) return;
      parts.push(`<rect x="${x(runStart)}" y="${y + 2}" width="${Math.max(0, x(end) - x(runStart))}" ` +
                 `height="${rowH - 6}" fill="${COLORS[runShown]}" shape-rendering="crispEdges"/>`);
    };
    segs.forEach(([start, shown]) => {
      const s = shown[String(n)] || "r";
      if (s === runShown) return;
      flush(start);
      runStart = start; runShown = s;
    });
    flush(t1);
  });
  const axisY = top + rowH * phases.length + 12;
  for (let s = 0; s <= w; s += 30) {
    const anchor = s === 0 ? "start" : s === w ? "end" : "middle";
    parts.push(`<text x="${x(t0 + s)}" y="${axisY}" font-size="11" fill="#6b7280" text-anchor="${anchor}">` +
               `${s === w ? "now" : "−" + (w - s) + " s"}</text>`);
  }
  svg.innerHTML = parts.join("");
  svg.setAttribute("xmlns", ns);
}

function drawManager(snap) {
  const state = $("state");
  state.textContent = STATES[snap.state] || snap.state;
  state.className = `state ${snap.state}`;
  state.dataset.state = snap.state;
  const to = snap.timeout;
  $("reason").textContent = to ? `reason: ${to.reason}${to.detail ? " — " + to.detail : ""}` +
                                 (to.recovering ? " (recovering…)" : "") : "";
  $("recover").hidden = !(meta && meta.control && snap.state === "timeout" && !snap.ended);
}

function drawCommands(snap) {
  const body = $("commands").tBodies[0];
  body.replaceChildren(...snap.commands.map((c) => el("tr", {},
    el("td", {}, String(c.id ?? "–")), el("td", {}, c.phases.join("+") + (c.green ? ` (${c.green}s)` : "")),
    el("td", {}, fmt(c.t, 1)), el("td", {}, fmt(c.verified_s)), el("td", {}, fmt(c.hold_s)),
    el("td", {}, c.outcome || "holding"))));
}

function drawComms(snap) {
  const c = snap.comms;
  const rows = [["polls answered", c.polls_ok], ["polls failed", c.polls_failed + (c.failing ? ` (${c.failing} in a row)` : "")],
                ["last verification lag", c.last_lag_s === null ? "–" : `${fmt(c.last_lag_s, 3)} s`],
                ["SETs sent / answered / failed", `${c.sets.sent} / ${c.sets.answered} / ${c.sets.failed}`],
                ["actions dropped / refused", `${c.dropped} / ${c.refused}`], ["drifted steps", c.drifts]];
  $("comms").replaceChildren(...rows.flatMap(([k, v]) => [el("dt", {}, k), el("dd", {}, String(v))]));
}

function drawQueues(snap) {
  const root = $("queues");
  if (!snap.queues) {
    root.replaceChildren(el("span", { class: "muted" }, "no traffic simulation in this run (or no sample yet)"));
    return;
  }
  const max = Math.max(1, ...Object.values(snap.queues));
  root.replaceChildren(...Object.entries(snap.queues).map(([name, q]) => el("div", { class: "qrow" },
    el("span", {}, name), el("div", { class: "qbar", style: `width:${(100 * q) / max}%` }), el("span", {}, String(q)))));
}

function draw(snap) {
  const run = snap.run || {};
  $("run").textContent = run.config ? `${run.config} · ${run.mode} · ${run.action_type} · agent ${run.agent}` : "waiting for the run…";
  $("clock").textContent = `t = ${fmt(snap.t, 1)} s`;
  $("status").textContent = snap.ended ? `run ended: ${snap.ended}` : meta.mode === "live" ? "live" : "replay";
  document.body.dataset.t = snap.t;
  drawRings(snap); drawCabinetNote(snap); drawManager(snap); drawCommands(snap); drawComms(snap); drawQueues(snap); drawStrip(snap);
}

function live() {
  const source = new EventSource("/api/stream");
  source.onmessage = (ev) => {
    const snap = JSON.parse(ev.data);
    draw(snap);
    if (snap.ended) source.close();
  };
  source.onerror = () => { $("status").textContent = "disconnected (run over?)"; };
  $("recover").onclick = async () => {
    const res = await fetch("/api/recover", { method: "POST" });
    $("recover-said").textContent = (await res.json()).recover || "refused";
  };
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
