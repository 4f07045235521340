// The sweepcast viewer: pick a rig and a source, orbit with the mouse, watch the virtual view.
//
// The page owns the rig, the source, the socket (see app/routers/rig_sockets.py for the protocol), the controls
// (controls.js), the orbit (orbit-input.js) and the status panel (status.js); a view draws the picture, behind one
// interface either way:
// - LocalView (local-view.js): this machine's GPU renders every view (render/), from frame sets the server ships
//   once (a recording's over HTTP, cached by the browser; the live stream's over the socket). The socket then
//   carries no viewpoints at all.
// - ServerView (server-view.js): viewpoints go out on the socket, JPEG frames come back.
// Render "auto" (the default) renders in the browser when it has WebGL2 with float render targets on a GPU (not a CPU
// rasteriser such as SwiftShader: the server is faster there, and the page goes to it at once) and holds the
// service's target rate at the chosen size, else on the server; ?render=browser|server forces one.
//
// Quality (workers/streaming/quality.py; the levels' options come in the socket's hello): "best" or "fast", or
// "auto": best where the renderer holds the target rate with it, else fast. The browser measures its own renders
// for that; the server's session measures its own. The advanced switches (depth, occlusions) override a level's.
import { api, authHeaders, rememberKey, startingKey } from "./api.js";
import { Controls } from "./controls.js";
import { LocalView } from "./local-view.js";
import { OrbitInput } from "./orbit-input.js";
import { capabilities } from "./render/gl.js";
import { unsupported } from "./render/renderer.js";
import { ServerView } from "./server-view.js";
import { hideError, hideNotice, notice, setState, showError, showMode, showStats, Stats } from "./status.js";

const $ = (id) => document.getElementById(id);
const query = new URLSearchParams(location.search);
const canvas = $("view");
const glCanvas = $("glview");
const gpu = capabilities(glCanvas);
const controls = new Controls();
const stats = new Stats();
const orbit = new OrbitInput(() => $("free-orbit").checked, () => {
  $("coverage").hidden = !orbit.outside;
  requestView();
});
const state = {
  key: startingKey(), rig: null, source: null, ws: null, hello: null,
  view: null, // the ServerView or LocalView shown
  forOptions: false, // the server renders because the browser cannot render the options
  frame: 0, frames: 0, fps: 0, player: null, sizeChosen: false,
  renderChoice: ["browser", "server"].includes(query.get("render")) ? query.get("render") : "auto",
};

/** What the views take from the page. */
const page = {
  controls, orbit, stats,
  get socket() { return state.ws; },
  get frame() { return state.source === "live" ? "live" : state.frame; },
  headers: () => authHeaders(state.key),
  /** The view can draw: show it. */
  onReady() {
    setState(state.source === "live" ? "live" : "ready");
    hideNotice();
    requestView();
  },
  /** A view is on screen: ``header`` the server's frame header or the browser renderer's info. */
  onShown(header) {
    hideError();
    showStats(stats, header, state.view, controls.depthOptions(), orbit, $("dbnd-auto").checked);
  },
  fallBack,
  /** An error of a view: ``record`` ({error, detail}) kept, ``text`` shown. */
  fail(record, text) {
    stats.errors.push(record);
    showError(text);
  },
};

// The page's state as the browser tests, the benchmarks and a console read it.
window.viewerState = Object.defineProperties({}, {
  ...Object.fromEntries(["received", "latencies", "captureLatencies", "errors", "firstFrameAt"].map((k) => [k, {
    get: () => stats[k], set: (v) => { stats[k] = v; } }])),
  ...Object.fromEntries(["azimuth", "elevation", "distance", "coverage"].map((k) => [k, { get: () => orbit[k] }])),
  ...Object.fromEntries(["hello", "frame"].map((k) => [k, { get: () => state[k] }])),
  gpu: { get: () => gpu.gpu },
  mode: { get: () => state.view?.mode ?? null },
  ready: { get: () => state.view?.ready ?? false },
  dirty: { get: () => state.view?.dirty ?? false },
  inFlight: { get: () => state.view?.inFlight ?? null },
  lastHeader: { get: () => state.view?.lastHeader ?? null },
  drawing: { get: () => state.view?.drawing ?? false },
  local: { get: () => state.view?.scene ?? null },
  level: { get: () => state.view?.level ?? null },
  lastInfo: { get: () => state.view?.lastInfo ?? null },
  renderTimes: { get: () => state.view?.renderTimes ?? [] },
  liveSeq: { get: () => state.view?.live?.seq ?? null },
});

// --- rigs and sources ---------------------------------------------------------------------------
async function loadRigs() {
  let rigs;
  try {
    ({ rigs } = await (await api("/v1/rigs", state.key)).json());
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
  const rig = await (await api(`/v1/rigs/${rigId}`, state.key)).json();
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

// --- which view ---------------------------------------------------------------------------------
/** The view to open the socket for: the browser's where asked for or possible, else the server's (with why). */
function chooseView() {
  const server = (why) => new ServerView(page, canvas, why);
  if (state.renderChoice === "server") return server("chosen");
  if (!gpu.ok) return server(gpu.reason);
  if (state.renderChoice === "auto" && gpu.software) return server(`WebGL runs on the CPU here (${gpu.gpu})`);
  const why = optionsWhy();
  if (why) return server(why);
  return new LocalView(page, glCanvas, gpu.gl, gpu.gpu, state.renderChoice === "auto");
}

/** Why the page's options render on the server only (null: the browser renders them). */
function optionsWhy() {
  return unsupported(controls.renderOptions(state.view?.level || "best"));
}

function fallBack(reason) {
  if (state.renderChoice === "browser") {
    showError(`cannot render in this browser: ${reason}`);
    return;
  }
  notice(`The server renders: ${reason}.`);
  setTimeout(hideNotice, 4000);
  connect(state.source, new ServerView(page, canvas, reason));
}

// --- the socket ---------------------------------------------------------------------------------
/** Open the socket for ``source`` with ``view`` (default: chooseView's). */
function connect(source, view = null) {
  if (state.ws) {
    state.ws.onclose = null;
    state.ws.close(1000);
  }
  stopPlaying();
  if (state.view) state.view.dispose();
  Object.assign(state, { source, hello: null, view: view ?? chooseView() });
  state.forOptions = state.view.mode === "server" && state.view.why === optionsWhy();
  canvas.hidden = state.view.mode !== "server";
  glCanvas.hidden = state.view.mode !== "browser";
  showMode(state.view);
  const url = new URL(`/v1/rigs/${state.rig}/view`, location.href);
  url.protocol = location.protocol === "https:" ? "wss:" : "ws:";
  url.searchParams.set("source", source);
  if (state.view.mode === "browser") url.searchParams.set("render", "browser");
  if (state.key) url.searchParams.set("access_token", state.key);
  const ws = new WebSocket(url);
  ws.binaryType = "arraybuffer";
  state.ws = ws;
  const shown = state.view;
  setState("connecting");
  ws.onmessage = (event) => {
    if (ws !== state.ws) return;
    if (typeof event.data === "string") onMessage(JSON.parse(event.data));
    else state.view.binary(event.data);
  };
  ws.onclose = (event) => {
    if (ws !== state.ws) return;
    shown.ready = false;
    setState(`closed${event.reason ? `: ${event.reason}` : ""}`);
    if (event.code !== 1008 && event.code !== 1003) {
      setTimeout(() => { if (ws === state.ws) connect(source, sameKind(shown)); }, 2000);
    }
  };
}

/** A new view of the kind of ``view`` (for a reconnect). */
function sameKind(view) {
  return view.mode === "server" ? new ServerView(page, canvas, view.why)
    : new LocalView(page, glCanvas, gpu.gl, gpu.gpu, view.mustHold);
}

async function onMessage(message) {
  if (message.type === "hello") {
    state.hello = message;
    controls.offer(message);
    orbit.setFrame(message.orbit);
    $("coverage").hidden = !orbit.outside;
    state.frames = message.frames || 0;
    state.fps = message.fps || 0;
    if (message.view_size && !state.sizeChosen) controls.startSize(message.view_size);
    $("timeline").hidden = !state.frames;
    $("frame").max = Math.max(state.frames - 1, 0);
    setFrame(Math.min(state.frame, Math.max(state.frames - 1, 0)), false);
    setState("starting the session");
    notice(state.view.mode === "browser" ? "Loading the frames into this browser…" : "Starting the session…");
    await state.view.start(message);
  } else if (message.type === "ready") {
    state.view.sessionReady();
  } else if (message.type === "error") {
    page.fail(message, `${message.error}: ${message.detail}`);
    state.view.failed(message);
  }
}

/** Show the view as the controls now say; ``byUser``: a user's change (its latency from now is measured). */
function requestView(byUser = true) {
  if (byUser) stats.changed();
  if (state.view) state.view.show();
}

// --- controls -----------------------------------------------------------------------------------
orbit.listen([canvas, glCanvas]);
for (const id of ["method", "overlay", "size", "planes"]) $(id).addEventListener("change", () => requestView());
$("quality").addEventListener("change", () => {
  if (state.view?.mode === "browser" || state.forOptions) connect(state.source); // measure this browser for the level
  else requestView();
});
for (const id of ["aggregation", "occlusions"]) {
  $(id).addEventListener("change", () => {
    const why = optionsWhy();
    if (state.view?.mode === "browser" && why) fallBack(why);
    else if (state.forOptions && !why) connect(state.source); // back to the browser
    else requestView();
  });
}
$("size").addEventListener("change", () => { state.sizeChosen = true; });
$("dbnd").addEventListener("input", () => {
  $("dbnd-auto").checked = false;
  $("dbnd-value").value = controls.dBnd;
  requestView();
});
$("dbnd-auto").addEventListener("change", () => requestView());
$("free-orbit").addEventListener("change", () => {
  orbit.keepInCoverage();
  $("coverage").hidden = !orbit.outside;
  requestView();
});
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
  rememberKey(state.key);
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

loadRigs();
