// The sweepcast viewer: pick a rig and a source, orbit with the mouse, watch the virtual view.
// Protocol (see app/routers/rig_sockets.py): viewpoints go out as JSON text; frames come back as
// binary messages = 4-byte big-endian header length, JSON header, JPEG. At most one viewpoint is in
// flight; changes made meanwhile are sent, as one viewpoint, when its frame arrives.
"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  const query = new URLSearchParams(location.search);
  const canvas = $("view");
  const draw = canvas.getContext("2d");
  const state = {
    key: query.get("key") || localStorage.getItem("sweepcast-key") || "",
    rig: null, source: null, ws: null, ready: false,
    orbit: null, azimuth: 0, elevation: 0, distance: 1,
    frame: 0, frames: 0, fps: 0, player: null,
    nextId: 1, inFlight: null, inFlightAt: 0, dirty: false, sentAt: new Map(),
    received: 0, arrivals: [], latencies: [], lastHeader: null, errors: [], sizeChosen: false,
  };
  window.viewerState = state; // read by the browser tests and handy in the console

  // --- REST -------------------------------------------------------------------------------------
  async function api(path) {
    const response = await fetch(path, { headers: state.key ? { Authorization: `Bearer ${state.key}` } : {} });
    if (!response.ok) {
      let detail = response.statusText;
      try { detail = (await response.json()).detail; } catch (_) { /* not JSON */ }
      const error = new Error(detail);
      error.status = response.status;
      throw error;
    }
    return response.json();
  }

  async function loadRigs() {
    let rigs;
    try {
      ({ rigs } = await api("/v1/rigs"));
    } catch (error) {
      showError(error.status === 401 ? "this service needs an API key: enter it below" : error.message);
      return;
    }
    if (!rigs.length) {
      notice("No rig yet. Add one with POST /v1/rigs (the demo rig appears on the first start).");
      setTimeout(loadRigs, 2000);
      return;
    }
    const select = $("rig");
    select.replaceChildren(...rigs.map((r) => new Option(`${r.name} (${r.cameras} cameras)`, r.id)));
    const wanted = rigs.find((r) => r.id === query.get("rig")) || rigs.find((r) => r.demo) || rigs[0];
    select.value = wanted.id;
    await selectRig(wanted.id);
  }

  async function selectRig(rigId) {
    state.rig = rigId;
    const rig = await api(`/v1/rigs/${rigId}`);
    if (state.rig !== rigId) return; // another rig was chosen meanwhile
    const options = rig.recordings.map((r) => {
      const label = r.state === "ready" ? `${r.name} (${r.frames} frames)`
        : r.state === "processing" ? `${r.name} (importing ${Math.round(100 * r.progress.fraction)}%)`
          : `${r.name} (${r.state})`;
      const option = new Option(label, r.id);
      option.disabled = r.state !== "ready";
      return option;
    });
    options.push(new Option("live stream", "live"));
    $("source").replaceChildren(...options);
    const ready = rig.recordings.filter((r) => r.state === "ready");
    const pending = rig.recordings.find((r) => r.state === "processing");
    const asked = query.get("source");
    if (asked && (asked === "live" || ready.some((r) => r.id === asked))) {
      $("source").value = asked;
    } else if (ready.length) {
      $("source").value = ready[ready.length - 1].id;
    } else if (pending) {
      notice(`Preparing “${pending.name}”: ${Math.round(100 * pending.progress.fraction)}% ${pending.progress.stage}`);
      setState("waiting for the recording");
      setTimeout(() => { if (state.rig === rigId) selectRig(rigId); }, 1000);
      return;
    } else {
      $("source").value = "live";
    }
    connect($("source").value);
  }

  // --- the socket -------------------------------------------------------------------------------
  function connect(source) {
    if (state.ws) {
      state.ws.onclose = null;
      state.ws.close(1000);
    }
    stopPlaying();
    Object.assign(state, { source, ready: false, inFlight: null, dirty: false });
    state.sentAt.clear();
    const url = new URL(`/v1/rigs/${state.rig}/view`, location.href);
    url.protocol = location.protocol === "https:" ? "wss:" : "ws:";
    url.searchParams.set("source", source);
    if (state.key) url.searchParams.set("access_token", state.key);
    const ws = new WebSocket(url);
    ws.binaryType = "arraybuffer";
    state.ws = ws;
    setState("connecting");
    ws.onmessage = (event) => {
      if (typeof event.data === "string") onMessage(JSON.parse(event.data));
      else onFrame(event.data);
    };
    ws.onclose = (event) => {
      if (ws !== state.ws) return;
      state.ready = false;
      setState(`closed${event.reason ? `: ${event.reason}` : ""}`);
      if (event.code !== 1008 && event.code !== 1003) setTimeout(() => { if (ws === state.ws) connect(source); }, 2000);
    };
  }

  function onMessage(message) {
    if (message.type === "hello") {
      state.orbit = message.orbit;
      state.frames = message.frames || 0;
      state.fps = message.fps || 0;
      if (message.view_size && !state.sizeChosen) startSize(message.view_size);
      goHome();
      $("timeline").hidden = !state.frames;
      $("frame").max = Math.max(state.frames - 1, 0);
      setFrame(Math.min(state.frame, Math.max(state.frames - 1, 0)), false);
      setState("starting the session");
      notice("Starting the session…");
    } else if (message.type === "ready") {
      state.ready = true;
      setState(state.source === "live" ? "live" : "ready");
      hideNotice();
      requestView();
    } else if (message.type === "error") {
      state.errors.push(message);
      showError(`${message.error}: ${message.detail}`);
      if (message.id !== undefined && message.id === state.inFlight) finishFlight();
    }
  }

  async function onFrame(buffer) {
    const length = new DataView(buffer).getUint32(0);
    const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, length)));
    const jpeg = new Blob([new Uint8Array(buffer, 4 + length)], { type: "image/jpeg" });
    const now = performance.now();
    const sent = state.sentAt.get(header.id);
    if (sent !== undefined) state.latencies.push(now - sent);
    for (const id of state.sentAt.keys()) if (id <= header.id) state.sentAt.delete(id);
    const bitmap = await createImageBitmap(jpeg);
    if (canvas.width !== header.width || canvas.height !== header.height) {
      canvas.width = header.width;
      canvas.height = header.height;
    }
    draw.drawImage(bitmap, 0, 0);
    bitmap.close();
    state.received += 1;
    state.lastHeader = header;
    state.arrivals.push(now);
    hideError();
    showStats(header);
    if (header.id === state.inFlight) finishFlight();
  }

  // --- viewpoints -------------------------------------------------------------------------------
  function viewpoint() {
    const [width, height] = $("size").value.split("x").map(Number);
    return {
      type: "view", id: state.nextId++, width, height, fov: 50,
      orbit: { azimuth: state.azimuth, elevation: state.elevation, distance: state.distance },
      method: $("method").value, d_bnd: dBnd(), planes: Number($("planes").value) || 48,
      aggregation: $("aggregation").value, occlusions: $("occlusions").value,
      frame: state.source === "live" ? "live" : state.frame, overlay: $("overlay").value, quality: 80,
    };
  }

  function requestView() {
    state.dirty = true;
    const stuck = state.inFlight !== null && performance.now() - state.inFlightAt > 10000;
    if (state.ready && state.ws && state.ws.readyState === WebSocket.OPEN && (state.inFlight === null || stuck)) {
      const vp = viewpoint();
      state.ws.send(JSON.stringify(vp));
      state.sentAt.set(vp.id, performance.now());
      state.inFlight = vp.id;
      state.inFlightAt = performance.now();
      state.dirty = false;
    }
  }

  function finishFlight() {
    state.inFlight = null;
    if (state.dirty) requestView();
  }

  function startSize([width, height]) {  // the server's default view size, until the user picks one
    const value = `${width}x${height}`;
    if (![...$("size").options].some((o) => o.value === value)) {
      const option = new Option(`${width}×${height}`, value);
      const after = [...$("size").options].find((o) => Number(o.value.split("x")[0]) > width);
      $("size").add(option, after || null);
    }
    $("size").value = value;
  }

  function goHome() {
    state.azimuth = 0;
    state.elevation = state.orbit ? state.orbit.elevation : 15;
    state.distance = state.orbit ? state.orbit.distance : 3;
  }

  function dBnd() {  // null: the server derives D_bnd from the rig
    if ($("dbnd-auto").checked) return null;
    return Number(Math.pow(10, Number($("dbnd").value)).toPrecision(3));
  }

  // --- mouse ------------------------------------------------------------------------------------
  let drag = null;
  canvas.addEventListener("pointerdown", (event) => {
    drag = { x: event.clientX, y: event.clientY };
    canvas.setPointerCapture(event.pointerId);
  });
  canvas.addEventListener("pointermove", (event) => {
    if (!drag) return;
    state.azimuth -= (event.clientX - drag.x) * 0.3;
    state.elevation = Math.max(-85, Math.min(85, state.elevation + (event.clientY - drag.y) * 0.25));
    drag = { x: event.clientX, y: event.clientY };
    requestView();
  });
  const endDrag = () => { drag = null; };
  canvas.addEventListener("pointerup", endDrag);
  canvas.addEventListener("pointercancel", endDrag);
  canvas.addEventListener("wheel", (event) => {
    event.preventDefault();
    const home = state.orbit ? state.orbit.distance : 3;
    state.distance = Math.max(0.1 * home, Math.min(10 * home, state.distance * Math.exp(event.deltaY * 0.0015)));
    requestView();
  }, { passive: false });
  canvas.addEventListener("dblclick", () => { goHome(); requestView(); });

  // --- controls ---------------------------------------------------------------------------------
  for (const id of ["method", "overlay", "size", "planes", "aggregation", "occlusions"]) $(id).addEventListener("change", requestView);
  $("size").addEventListener("change", () => { state.sizeChosen = true; });
  $("dbnd").addEventListener("input", () => {
    $("dbnd-auto").checked = false;
    $("dbnd-value").value = dBnd();
    requestView();
  });
  $("dbnd-auto").addEventListener("change", requestView);
  $("rig").addEventListener("change", () => selectRig($("rig").value));
  $("source").addEventListener("change", () => connect($("source").value));
  $("frame").addEventListener("input", () => setFrame(Number($("frame").value), true));
  $("play").addEventListener("click", () => (state.player ? stopPlaying() : startPlaying()));
  $("key").value = state.key;
  $("key").addEventListener("change", () => {
    state.key = $("key").value.trim();
    localStorage.setItem("sweepcast-key", state.key);
    loadRigs();
  });

  function setFrame(index, render) {
    state.frame = index;
    $("frame").value = index;
    $("frame-value").value = `${index + 1}/${state.frames}`;
    if (render) requestView();
  }

  function startPlaying() {
    if (!state.frames) return;
    $("play").textContent = "❚❚";
    state.player = setInterval(() => setFrame((state.frame + 1) % state.frames, true), 1000 / (state.fps || 10));
  }

  function stopPlaying() {
    clearInterval(state.player);
    state.player = null;
    $("play").textContent = "▶";
  }

  // --- status -----------------------------------------------------------------------------------
  function showStats(header) {
    const now = performance.now();
    state.arrivals = state.arrivals.filter((t) => now - t <= 2000);
    state.latencies = state.latencies.slice(-50);
    const sorted = [...state.latencies].sort((a, b) => a - b);
    const pick = (q) => (sorted.length ? sorted[Math.min(sorted.length - 1, Math.floor(q * sorted.length))] : NaN);
    $("fps").textContent = (state.arrivals.length / 2).toFixed(1);
    $("latency").textContent = sorted.length ? `p50 ${pick(0.5).toFixed(0)} ms · p95 ${pick(0.95).toFixed(0)} ms` : "–";
    $("render").textContent = `${header.render_ms.toFixed(0)} ms${header.reshaded ? " (re-shaded)" : ""} + JPEG ${header.encode_ms.toFixed(0)} ms`;
    if (header.d_bnd !== null && header.d_bnd !== undefined) {
      $("dbnd-value").value = `${Number(header.d_bnd).toPrecision(3)}${$("dbnd-auto").checked ? " (auto)" : ""}`;
    }
    $("pose").textContent = `az ${state.azimuth.toFixed(0)}° el ${state.elevation.toFixed(0)}° d ${state.distance.toFixed(2)}`;
    $("depth").textContent = header.depth_found
      ? `${header.depth_found[0].toFixed(2)}–${header.depth_found[1].toFixed(2)} (swept ${header.depth_range[0].toFixed(2)}–${header.depth_range[1].toFixed(2)})`
      : "no surface";
  }

  function setState(text) { $("state").textContent = text; }
  function notice(text) { $("notice").textContent = text; $("notice").hidden = false; }
  function hideNotice() { $("notice").hidden = true; }
  function showError(text) { $("error").textContent = text; $("error").hidden = false; }
  function hideError() { $("error").hidden = true; }

  loadRigs();
})();
