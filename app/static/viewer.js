// The sweepcast viewer: pick a rig and a source, orbit with the mouse, watch the virtual view.
//
// Two ways to render (see app/routers/rig_sockets.py for the socket protocol):
// - browser: this machine's GPU renders every view (local-view.js, render/), from frame sets the server ships
//   once (a recording's over HTTP, cached by the browser; the live stream's over the socket). The socket then
//   carries no viewpoints at all.
// - server: viewpoints go out as JSON text; frames come back as binary messages = 4-byte big-endian header
//   length, JSON header, JPEG. At most one viewpoint is in flight; changes made meanwhile are sent, as one
//   viewpoint, when its frame arrives.
// "auto" (the default) renders in the browser when it has WebGL2 with float render targets on a GPU (not a CPU
// rasteriser such as SwiftShader: the server is faster there, and the page goes to it at once) and holds the
// service's target rate at the chosen size, else on the server; ?render=browser|server forces one.
//
// Quality (workers/streaming/quality.py; the levels' options come in the socket's hello): "best" or "fast", or
// "auto": best where the renderer holds the target rate with it, else fast. The browser measures its own renders
// for that; the server's session measures its own. The advanced switches (depth, occlusions) override a level's.
import { LocalView } from "./local-view.js";
import { capabilities } from "./render/gl.js";
import { Unsupported, unsupported } from "./render/renderer.js";
import { clampAzimuth, orbitCamera, orbitCoverage } from "./render/rig.js";

const $ = (id) => document.getElementById(id);
const query = new URLSearchParams(location.search);
const canvas = $("view");
const glCanvas = $("glview");
const draw = canvas.getContext("2d");
const PROBE_RENDERS = 3; // renders timed before auto mode keeps the browser
const state = {
  key: query.get("key") || localStorage.getItem("sweepcast-key") || "",
  rig: null, source: null, ws: null, ready: false, hello: null,
  orbit: null, coverage: null, azimuth: 0, elevation: 0, distance: 1, outside: false,
  frame: 0, frames: 0, fps: 0, player: null,
  nextId: 1, inFlight: null, inFlightAt: 0, dirty: false, sentAt: new Map(), changedAt: null,
  received: 0, arrivals: [], latencies: [], lastHeader: null, errors: [], sizeChosen: false,
  captureLatencies: [], liveCaptured: null, // live: ms from each shown set's capture time to its frame here
  liveBusy: false, livePending: null, liveDropped: 0, liveResync: false, // browser rendering of live sets
  // browser rendering
  renderChoice: ["browser", "server"].includes(query.get("render")) ? query.get("render") : "auto",
  mode: null, why: "", forOptions: false, gpu: null, local: null, drawing: false, renderTimes: [], lastInfo: null, liveSeq: null,
  levels: null, level: null, // the hello's quality levels; the level this browser renders at
  firstFrameAt: null, // performance.now() when the first view was drawn (ms since the page's navigation started)
};
window.viewerState = state; // read by the browser tests and handy in the console

const gpu = capabilities(glCanvas);
state.gpu = gpu.gpu;

// --- REST -------------------------------------------------------------------------------------
function authHeaders() {
  return state.key ? { Authorization: `Bearer ${state.key}` } : {};
}

async function api(path) {
  const response = await fetch(path, { headers: authHeaders() });
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

// --- which renderer -----------------------------------------------------------------------------
/** The mode to open the socket in: browser where asked for or possible, else server (with the reason). */
function chooseMode() {
  if (state.renderChoice === "server") return ["server", "chosen"];
  if (!gpu.ok) return ["server", gpu.reason];
  if (state.renderChoice === "auto" && gpu.software) return ["server", `WebGL runs on the CPU here (${gpu.gpu})`];
  const why = unsupported(renderOptions());
  if (why) return ["server", why];
  return ["browser", state.renderChoice === "browser" ? "chosen" : "auto"];
}

function fallBack(reason) {
  if (state.renderChoice === "browser") {
    showError(`cannot render in this browser: ${reason}`);
    return;
  }
  notice(`The server renders: ${reason}.`);
  setTimeout(hideNotice, 4000);
  connect(state.source, "server", reason);
}

// --- the socket -------------------------------------------------------------------------------
function connect(source, mode = null, why = null) {
  if (state.ws) {
    state.ws.onclose = null;
    state.ws.close(1000);
  }
  stopPlaying();
  if (state.local) {
    state.local.dispose();
    state.local = null;
  }
  [state.mode, state.why] = mode ? [mode, why] : chooseMode();
  state.forOptions = state.mode === "server" && state.why === unsupported(renderOptions());
  Object.assign(state, { source, ready: false, inFlight: null, dirty: false, hello: null, renderTimes: [],
    liveSeq: null, livePending: null, liveResync: false });
  state.sentAt.clear();
  canvas.hidden = state.mode !== "server";
  glCanvas.hidden = state.mode !== "browser";
  showMode();
  const url = new URL(`/v1/rigs/${state.rig}/view`, location.href);
  url.protocol = location.protocol === "https:" ? "wss:" : "ws:";
  url.searchParams.set("source", source);
  if (state.mode === "browser") url.searchParams.set("render", "browser");
  if (state.key) url.searchParams.set("access_token", state.key);
  const ws = new WebSocket(url);
  ws.binaryType = "arraybuffer";
  state.ws = ws;
  setState("connecting");
  ws.onmessage = (event) => {
    if (ws !== state.ws) return;
    if (typeof event.data === "string") onMessage(JSON.parse(event.data));
    else if (state.mode === "browser") onLiveSet(event.data);
    else onFrame(event.data);
  };
  ws.onclose = (event) => {
    if (ws !== state.ws) return;
    state.ready = false;
    setState(`closed${event.reason ? `: ${event.reason}` : ""}`);
    if (event.code !== 1008 && event.code !== 1003) setTimeout(() => { if (ws === state.ws) connect(source, state.mode, state.why); }, 2000);
  };
}

async function onMessage(message) {
  if (message.type === "hello") {
    state.hello = message;
    offerControls(message.controls);
    state.levels = message.quality_levels;
    state.orbit = message.orbit;
    state.coverage = orbitCoverage(message.orbit);
    state.frames = message.frames || 0;
    state.fps = message.fps || 0;
    if (message.view_size && !state.sizeChosen) startSize(message.view_size);
    goHome();
    $("timeline").hidden = !state.frames;
    $("frame").max = Math.max(state.frames - 1, 0);
    setFrame(Math.min(state.frame, Math.max(state.frames - 1, 0)), false);
    setState("starting the session");
    notice(state.mode === "browser" ? "Loading the frames into this browser…" : "Starting the session…");
    if (state.mode === "browser") await openLocal(message);
  } else if (message.type === "ready") {
    if (state.mode === "browser") return; // openLocal marks it ready once the frames are on the GPU
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
  state.firstFrameAt ??= performance.now();
  state.received += 1;
  state.lastHeader = header;
  state.arrivals.push(now);
  if (header.frame === "live") {
    noteCaptured(header.captured);
    showSpread(header);
  }
  hideError();
  showStats(header);
  if (header.id === state.inFlight) finishFlight();
}

// --- browser rendering -------------------------------------------------------------------------
async function openLocal(hello) {
  const ws = state.ws;
  try {
    const local = await LocalView.open(gpu.gl, hello, authHeaders());
    if (ws !== state.ws) { local.dispose(); return; }
    state.local = local;
    const [width, height] = viewSize();
    await local.prepare(state.frame, width, height);
    if (ws !== state.ws) return;
    const level = chooseLevel(hello.target_fps);
    if (level === null) {
      const ms = state.renderTimes.at(-1);
      fallBack(`this browser takes ${ms.toFixed(0)} ms per ${width}×${height} view (${(1000 / ms).toFixed(1)} fps; `
        + `the target is ${hello.target_fps} fps)`);
      return;
    }
    state.level = level;
    state.ready = true;
    setState(state.source === "live" ? "live" : "ready");
    hideNotice();
    requestView();
  } catch (error) {
    if (ws === state.ws) fallBack(`the browser renderer failed (${error.message})`);
  }
}

/** The quality level this browser renders at: the one asked for, or with "auto" the best that holds
 * ``targetFps`` at the chosen size (measured; fast when none does); null when Render is auto and the level(s)
 * asked for miss the rate: the server renders then. Fast is measured first, and best only where fast takes at most
 * half the frame budget (best costs two to four times fast), as the server's sessions choose
 * (workers/streaming/quality.py QualityChooser). */
function chooseLevel(targetFps) {
  const asked = $("quality").value;
  const mustHold = state.renderChoice === "auto";
  if (asked !== "auto" && !mustHold) return asked;
  const budget = 1000 / targetFps;
  const measured = (level) => {
    const ms = probe(budget, level);
    state.renderTimes = [ms];
    return ms;
  };
  if (asked !== "auto") return measured(asked) <= budget ? asked : null;
  const fast = measured("fast");
  if (fast > budget) return mustHold ? null : "fast";
  return fast <= budget / 2 && measured("best") <= budget ? "best" : "fast";
}

/** Median ms of a few renders of the current view at ``level``. The first also compiles the shaders: it is counted
 * only when it alone is far over ``budget`` ms (a software renderer: no need to wait for more). */
function probe(budget, level) {
  const time = () => {
    const t0 = performance.now();
    state.local.draw(virtualCamera(), renderOptions(level), "none");
    return performance.now() - t0;
  };
  time(); // the first draw compiles the shader programs (seconds on SwiftShader, and not a frame's cost anywhere)
  const first = time();
  if (first > 4 * budget) return first;
  const times = Array.from({ length: PROBE_RENDERS }, time).sort((a, b) => a - b);
  return times[Math.floor(times.length / 2)];
}

/** A live set from the socket. Sets arrive while the previous one is still being decoded and uploaded (the
 * socket's bytes are taken off the network before this handler runs, so the server cannot hold them back): only the
 * newest waits, the others are dropped (counted in liveDropped), so no delay builds up. A dropped set that was the
 * empty scene makes the next one fetch the server's background model again. */
async function onLiveSet(buffer) {
  if (!state.local) return;
  if (state.liveBusy) {
    if (state.livePending) {
      state.liveDropped += 1;
      state.liveResync ||= liveHeader(state.livePending).header.background;
    }
    state.livePending = buffer;
    return;
  }
  state.liveBusy = true;
  try {
    for (let next = buffer; next; next = state.livePending, state.livePending = null) await showLiveSet(next);
  } finally {
    state.liveBusy = false;
  }
}

function liveHeader(buffer) {
  const length = new DataView(buffer).getUint32(0);
  return { header: JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, length))), length };
}

async function showLiveSet(buffer) {
  const { header, length } = liveHeader(buffer);
  if (state.liveResync) {
    header.resync = true;
    state.liveResync = false;
  }
  const jpegs = [];
  let offset = 4 + length;
  for (const size of header.sizes) {
    jpegs.push(new Uint8Array(buffer, offset, size));
    offset += size;
  }
  showSpread(header);
  const seq = await state.local.liveSet(header, jpegs);
  if (seq === null) return; // stale cameras: the last complete set stays on show
  state.liveSeq = seq;
  state.liveCaptured = header.captured ?? null;
  requestView(false);
}

/** Draw the current view on this GPU (at most once per display frame, the latest state wins). */
function drawLocal() {
  if (state.drawing) return;
  state.drawing = true;
  requestAnimationFrame(async () => {
    try {
      const [width, height] = viewSize();
      const changedAt = state.changedAt;
      state.dirty = false;
      state.changedAt = null;
      await state.local.prepare(state.frame, width, height);
      if (glCanvas.width !== width || glCanvas.height !== height) {
        glCanvas.width = width;
        glCanvas.height = height;
      }
      const info = state.local.draw(virtualCamera(), renderOptions(), $("overlay").value);
      const now = performance.now();
      if (changedAt !== null) state.latencies.push(now - changedAt);
      state.renderTimes.push(info.ms);
      state.renderTimes = state.renderTimes.slice(-30);
      state.lastInfo = info;
      state.firstFrameAt ??= now;
      state.received += 1;
      state.arrivals.push(now);
      if (state.source === "live") noteCaptured(state.liveCaptured);
      hideError();
      showStats({ ...info, render_ms: info.ms, frame: state.source === "live" ? "live" : state.frame });
    } catch (error) {
      if (error instanceof Unsupported) {
        fallBack(error.message);
        return;
      }
      state.errors.push({ error: "browser_render", detail: error.message });
      showError(`browser render: ${error.message}`);
    } finally {
      state.drawing = false;
      if (state.dirty) drawLocal();
    }
  });
}

// --- what a viewer may ask for ------------------------------------------------------------------
let controls = null; // the hello's controls (workers/streaming/rules.py viewpoint_controls), once one came

/** Offer the hello's choices in the page's menus and its planes limit; the first hello's defaults select. */
function offerControls(offered) {
  const first = controls === null;
  controls = offered;
  const menus = { method: "method", aggregation: "aggregation", occlusions: "occlusions", overlay: "overlay",
    quality: "render_quality" };
  for (const [id, field] of Object.entries(menus)) {
    offer($(id), offered.choices[field], first ? offered.defaults[field] ?? "" : $(id).value);
  }
  $("planes").max = offered.planes.max;
  if (first) $("planes").value = offered.defaults.planes;
}

/** Make ``values`` the options of ``select``, labelled as the page labels them (a value it has no label for by
 * itself), after its "" option (as the quality level) where it has one; ``selected`` is selected if offered. */
function offer(select, values, selected) {
  const labels = new Map([...select.options].map((o) => [o.value, o.text]));
  const keep = labels.has("") ? ["", ...values] : values;
  select.replaceChildren(...keep.map((v) => new Option(labels.get(v) ?? v, v)));
  if (keep.includes(selected)) select.value = selected;
}

// --- viewpoints -------------------------------------------------------------------------------
function viewSize() {
  return $("size").value.split("x").map(Number);
}

/** The depth options the advanced switches set (aggregation, occlusions): null where they leave it to the level. */
function ownDepthOptions() {
  return { aggregation: $("aggregation").value || null, occlusions: $("occlusions").value || null };
}

/** The renderer's options (RenderOptions' fields) a viewpoint of the page asks for at quality ``level`` ("best",
 * "fast"; default the level this browser renders at, else best), as the server's session makes them
 * (SweepSettings.render_fields): a viewpoint's defaults (the hello's controls) under the page's switches, the level's
 * where they leave them. Before a hello: the page's switches alone. */
function renderOptions(level = state.level || "best") {
  const preset = (state.levels && state.levels[level]) || {};
  const own = ownDepthOptions();
  const depth = {};
  for (const key of Object.keys(own)) {
    const value = own[key] ?? preset[key];
    if (value) depth[key] = value;
  }
  const fields = state.hello?.render ? Object.keys(state.hello.render.rules.defaults) : [];
  const defaults = Object.fromEntries(fields.filter((k) => k in controls.defaults).map((k) => [k, controls.defaults[k]]));
  return { ...defaults, ...pageOptions(), ...depth };
}

/** The renderer's options the page's controls set, those of the quality level apart. */
function pageOptions() {
  return { method: $("method").value, d_bnd: dBnd(), planes: Number($("planes").value) || controls?.defaults.planes };
}

/** What runs, as the frame header's "quality" says it: the level, or "custom" where a switch differs from it. */
function levelRun(level) {
  const preset = (state.levels && state.levels[level]) || {};
  const own = ownDepthOptions();
  return Object.keys(own).some((k) => own[k] !== null && own[k] !== preset[k]) ? "custom" : level;
}

function virtualCamera() {
  const [width, height] = viewSize();
  return orbitCamera(state.orbit, { azimuth: state.azimuth, elevation: state.elevation, distance: state.distance },
    controls.defaults.fov, width, height);
}

function viewpoint() {
  const [width, height] = viewSize();
  return {
    type: "view", id: state.nextId++, width, height,
    orbit: { azimuth: state.azimuth, elevation: state.elevation, distance: state.distance },
    ...pageOptions(), ...ownDepthOptions(), render_quality: $("quality").value,
    frame: state.source === "live" ? "live" : state.frame, overlay: $("overlay").value,
  };
}

/** Show the view as the controls now say; ``byUser``: a user's change (its latency from now is measured). */
function requestView(byUser = true) {
  state.dirty = true;
  if (byUser && state.changedAt === null) state.changedAt = performance.now();
  if (state.mode === "browser") {
    if (state.ready && state.local) drawLocal();
    return;
  }
  const stuck = state.inFlight !== null && performance.now() - state.inFlightAt > 10000;
  if (state.ready && state.ws && state.ws.readyState === WebSocket.OPEN && (state.inFlight === null || stuck)) {
    const vp = viewpoint();
    state.ws.send(JSON.stringify(vp));
    state.sentAt.set(vp.id, state.changedAt ?? performance.now());
    state.changedAt = null;
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
  state.outside = false;
}

function dBnd() {  // null: derived from the rig (the server's rule, computed where the view is rendered)
  if ($("dbnd-auto").checked) return null;
  return Number(Math.pow(10, Number($("dbnd").value)).toPrecision(3));
}

/** Keep the orbit within the cameras' coverage unless the user unlocked it; say when it is outside. */
function keepInCoverage() {
  const cov = state.coverage;
  if (!cov) return;
  const az = clampAzimuth(state.azimuth, cov.azimuth);
  const elInside = state.elevation >= cov.elevation[0] && state.elevation <= cov.elevation[1];
  if ($("free-orbit").checked) {
    state.outside = !az.inside || !elInside;
  } else {
    state.azimuth = az.azimuth;
    state.elevation = Math.max(cov.elevation[0], Math.min(cov.elevation[1], state.elevation));
    state.outside = false;
  }
  $("coverage").hidden = !state.outside;
}

// --- mouse ------------------------------------------------------------------------------------
let drag = null;
for (const target of [canvas, glCanvas]) {
  target.addEventListener("pointerdown", (event) => {
    drag = { x: event.clientX, y: event.clientY };
    target.setPointerCapture(event.pointerId);
  });
  target.addEventListener("pointermove", (event) => {
    if (!drag) return;
    state.azimuth -= (event.clientX - drag.x) * 0.3;
    state.elevation = Math.max(-85, Math.min(85, state.elevation + (event.clientY - drag.y) * 0.25));
    drag = { x: event.clientX, y: event.clientY };
    keepInCoverage();
    requestView();
  });
  const endDrag = () => { drag = null; };
  target.addEventListener("pointerup", endDrag);
  target.addEventListener("pointercancel", endDrag);
  target.addEventListener("wheel", (event) => {
    event.preventDefault();
    const home = state.orbit ? state.orbit.distance : 3;
    state.distance = Math.max(0.1 * home, Math.min(10 * home, state.distance * Math.exp(event.deltaY * 0.0015)));
    requestView();
  }, { passive: false });
  target.addEventListener("dblclick", () => { goHome(); keepInCoverage(); requestView(); });
}

// --- controls ---------------------------------------------------------------------------------
for (const id of ["method", "overlay", "size", "planes"]) $(id).addEventListener("change", requestView);
$("quality").addEventListener("change", () => {
  if (state.mode === "browser" || state.forOptions) connect(state.source); // measure this browser for the level
  else requestView();
});
for (const id of ["aggregation", "occlusions"]) {
  $(id).addEventListener("change", () => {
    const why = unsupported(renderOptions());
    if (state.mode === "browser" && why) fallBack(why);
    else if (state.mode === "server" && state.forOptions && !why) connect(state.source); // back to the browser
    else requestView();
  });
}
$("size").addEventListener("change", () => { state.sizeChosen = true; });
$("dbnd").addEventListener("input", () => {
  $("dbnd-auto").checked = false;
  $("dbnd-value").value = dBnd();
  requestView();
});
$("dbnd-auto").addEventListener("change", requestView);
$("free-orbit").addEventListener("change", () => { keepInCoverage(); requestView(); });
$("rig").addEventListener("change", () => selectRig($("rig").value));
$("source").addEventListener("change", () => connect($("source").value));
$("frame").addEventListener("input", () => setFrame(Number($("frame").value), true));
$("play").addEventListener("click", () => (state.player ? stopPlaying() : startPlaying()));
$("render-choice").value = state.renderChoice;
$("render-choice").addEventListener("change", () => {
  state.renderChoice = $("render-choice").value;
  if (state.rig && state.source) connect(state.source);
});
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
function showMode() {
  const where = state.mode === "browser" ? `this browser (${state.gpu || "WebGL2"})`
    : `the server${state.why && !["chosen", "auto"].includes(state.why) ? ` (${state.why})` : ""}`;
  $("mode").textContent = where;
}

const LEVEL_TEXT = { best: "best: semi-global depth, occlusions filled", fast: "fast: semi-global depth" };

/** The quality shown: the level that ran (the server's frame header says it; this browser knows its own). */
function showQuality(header) {
  const runs = state.mode === "browser" ? levelRun(state.level) : header.quality;
  const asked = state.mode === "browser" ? $("quality").value : header.quality_asked;
  if (!runs) return;
  const own = ownDepthOptions();
  const text = runs === "custom"
    ? `custom: ${own.aggregation ?? "the level's"} depth, occlusions ${own.occlusions ?? "as the level"}`
    : LEVEL_TEXT[runs] ?? runs;
  $("quality-shown").textContent = asked === "auto" ? `${text} (auto)` : text;
}

function showStats(header) {
  showQuality(header);
  const now = performance.now();
  state.arrivals = state.arrivals.filter((t) => now - t <= 2000);
  state.latencies = state.latencies.slice(-50);
  const sorted = [...state.latencies].sort((a, b) => a - b);
  const pick = (q) => (sorted.length ? sorted[Math.min(sorted.length - 1, Math.floor(q * sorted.length))] : NaN);
  $("fps").textContent = (state.arrivals.length / 2).toFixed(1);
  $("latency").textContent = sorted.length ? `p50 ${pick(0.5).toFixed(0)} ms · p95 ${pick(0.95).toFixed(0)} ms` : "–";
  $("render").textContent = state.mode === "browser" ? `${header.render_ms.toFixed(1)} ms on this GPU`
    : `${header.render_ms.toFixed(0)} ms${header.reshaded ? " (re-shaded)" : ""} + JPEG ${header.encode_ms.toFixed(0)} ms`;
  if (header.d_bnd !== null && header.d_bnd !== undefined) {
    $("dbnd-value").value = `${Number(header.d_bnd).toPrecision(3)}${$("dbnd-auto").checked ? " (auto)" : ""}`;
  }
  $("pose").textContent = `az ${state.azimuth.toFixed(0)}° el ${state.elevation.toFixed(0)}° d ${state.distance.toFixed(2)}`;
  $("depth").textContent = header.depth_found
    ? `${header.depth_found[0].toFixed(2)}–${header.depth_found[1].toFixed(2)} (swept ${header.depth_range[0].toFixed(2)}–${header.depth_range[1].toFixed(2)})`
    : "no surface";
}

/** A live set's spread of capture times and its stale cameras (frame header or relayed set header). */
function showSpread(header) {
  const stale = header.stale && header.stale.length ? ` · stale: ${header.stale.join(", ")}` : "";
  $("spread").textContent = header.spread_ms === null || header.spread_ms === undefined ? `unknown${stale}`
    : `${Number(header.spread_ms).toFixed(1)} ms${stale}`;
}

/** Capture-to-frame: from a live set's capture time (its instant, s since the epoch, on the cameras' clock) to
 * the frame on this screen now (meaningful where this machine's clock and the cameras' agree). */
function noteCaptured(captured) {
  if (captured === null || captured === undefined) return;
  state.captureLatencies.push(Date.now() - captured * 1000);
  state.captureLatencies = state.captureLatencies.slice(-200);
}

function setState(text) { $("state").textContent = text; }
function notice(text) { $("notice").textContent = text; $("notice").hidden = false; }
function hideNotice() { $("notice").hidden = true; }
function showError(text) { $("error").textContent = text; $("error").hidden = false; }
function hideError() { $("error").hidden = true; }

loadRigs();
