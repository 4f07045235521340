// A view this browser renders on its GPU (render/, through browser-scene.js) from frame sets the server ships once;
// the socket then carries no viewpoints, only the live stream's sets. It renders at a quality level ("best" or
// "fast", the hello's levels: workers/streaming/quality.py) it measured itself, as the server's sessions choose, and
// draws at most once per display frame, the latest controls winning. The page drives it as it drives a ServerView
// (server-view.js): start, sessionReady, binary, failed, show, quality, renderText, dispose.
import { BrowserScene } from "./browser-scene.js";
import { unpackMessage, splitPayload } from "./framing.js";
import { Unsupported } from "./render/renderer.js";
import { orbitCamera } from "./render/rig.js";
import { showSpread } from "./status.js";

const PROBE_RENDERS = 3; // renders timed before auto quality keeps a level

export class LocalView {
  /** page: the viewer page (viewer.js); canvas: its WebGL2 canvas, ``gl`` its context and ``gpu`` the GPU's name;
   * mustHold: the page's Render is auto, so a level that misses the target rate sends the view to the server. */
  constructor(page, canvas, gl, gpu, mustHold) {
    Object.assign(this, { page, canvas, gl, gpu, mustHold, mode: "browser", why: null });
    this.scene = null; // the GPU's (BrowserScene), once loaded
    this.hello = null;
    this.level = null; // the quality level this browser renders at
    this.ready = false;
    this.dirty = false; // a change waits to be drawn
    this.drawing = false; // a draw is scheduled or under way
    this.renderTimes = []; // ms of the last renders (the probe's, then the last 30 drawn)
    this.lastInfo = null; // the renderer's info of the last view drawn
    this.live = { seq: null, captured: null, busy: false, pending: null, dropped: 0, resync: false };
    this.disposed = false;
  }

  /** Load the hello's frames onto the GPU and choose the quality level; the page is told when the view can be drawn,
   * or falls back to the server (a level that misses the target rate with Render auto, a renderer that fails). */
  async start(hello) {
    try {
      const scene = await BrowserScene.open(this.gl, hello, this.page.headers());
      if (this.disposed) {
        scene.dispose();
        return;
      }
      Object.assign(this, { scene, hello });
      const [width, height] = this.page.controls.size;
      await scene.prepare(this.page.frame, width, height);
      if (this.disposed) return;
      const level = this.chooseLevel(hello.target_fps);
      if (level === null) {
        const ms = this.renderTimes.at(-1);
        this.page.fallBack(`this browser takes ${ms.toFixed(0)} ms per ${width}×${height} view (${(1000 / ms).toFixed(1)} `
          + `fps; the target is ${hello.target_fps} fps)`);
        return;
      }
      this.level = level;
      this.ready = true;
      this.page.onReady();
    } catch (error) {
      if (!this.disposed) this.page.fallBack(`the browser renderer failed (${error.message})`);
    }
  }

  /** The session's ready: this view is ready once its frames are on the GPU (start). */
  sessionReady() {}

  /** The quality level this browser renders at: the one asked for, or with "auto" the best that holds
   * ``targetFps`` at the chosen size (measured; fast when none does); null when Render is auto and the level(s)
   * asked for miss the rate: the server renders then. Fast is measured first, and best only where fast takes at most
   * half the frame budget (best costs two to four times fast), as the server's sessions choose
   * (workers/streaming/quality.py QualityChooser). */
  chooseLevel(targetFps) {
    const asked = this.page.controls.quality;
    if (asked !== "auto" && !this.mustHold) return asked;
    const budget = 1000 / targetFps;
    const measured = (level) => {
      const ms = this.probe(budget, level);
      this.renderTimes = [ms];
      return ms;
    };
    if (asked !== "auto") return measured(asked) <= budget ? asked : null;
    const fast = measured("fast");
    if (fast > budget) return this.mustHold ? null : "fast";
    return fast <= budget / 2 && measured("best") <= budget ? "best" : "fast";
  }

  /** Median ms of a few renders of the current view at ``level``. The first also compiles the shaders: it is counted
   * only when it alone is far over ``budget`` ms (a software renderer: no need to wait for more). */
  probe(budget, level) {
    const time = () => {
      const t0 = performance.now();
      this.scene.draw(this.camera(), this.renderOptions(level), "none");
      return performance.now() - t0;
    };
    time(); // the first draw compiles the shader programs (seconds on SwiftShader, and not a frame's cost anywhere)
    const first = time();
    if (first > 4 * budget) return first;
    const times = Array.from({ length: PROBE_RENDERS }, time).sort((a, b) => a - b);
    return times[Math.floor(times.length / 2)];
  }

  /** The virtual camera of the orbit now, at the chosen size and the viewpoint's default field of view. */
  camera() {
    const [width, height] = this.page.controls.size;
    return orbitCamera(this.hello.orbit, this.page.orbit.pose, this.page.controls.defaultOf("fov"), width, height);
  }

  /** The renderer's options at ``level`` (default the level this browser renders at), as a session makes them. */
  renderOptions(level = this.level || "best") {
    return this.page.controls.renderOptions(level, Object.keys(this.hello.render.rules.defaults));
  }

  /** Draw the view the controls now describe (at most once per display frame, the latest state wins). */
  show() {
    this.dirty = true;
    if (!this.ready || this.drawing) return;
    this.drawing = true;
    requestAnimationFrame(() => this.draw());
  }

  async draw() {
    const { controls, stats } = this.page;
    try {
      const [width, height] = controls.size;
      const since = stats.takeChange();
      this.dirty = false;
      await this.scene.prepare(this.page.frame, width, height);
      if (this.disposed) return;
      if (this.canvas.width !== width || this.canvas.height !== height) {
        this.canvas.width = width;
        this.canvas.height = height;
      }
      const info = this.scene.draw(this.camera(), this.renderOptions(), controls.overlay);
      this.renderTimes = [...this.renderTimes, info.ms].slice(-30);
      this.lastInfo = info;
      stats.shown(since);
      if (this.page.frame === "live") stats.captured(this.live.captured);
      this.page.onShown({ ...info, render_ms: info.ms, frame: this.page.frame });
    } catch (error) {
      if (this.disposed) return;
      if (error instanceof Unsupported) this.page.fallBack(error.message);
      else this.page.fail({ error: "browser_render", detail: error.message }, `browser render: ${error.message}`);
    } finally {
      this.drawing = false;
      if (this.dirty && !this.disposed) this.show();
    }
  }

  /** A live set from the socket. Sets arrive while the previous one is still being decoded and uploaded (the
   * socket's bytes are taken off the network before this handler runs, so the server cannot hold them back): only the
   * newest waits, the others are dropped (counted in live.dropped), so no delay builds up. A dropped set that was the
   * empty scene makes the next one fetch the server's background model again. */
  async binary(buffer) {
    const live = this.live;
    if (!this.scene) return;
    if (live.busy) {
      if (live.pending) {
        live.dropped += 1;
        live.resync ||= unpackMessage(live.pending).header.background;
      }
      live.pending = buffer;
      return;
    }
    live.busy = true;
    try {
      for (let next = buffer; next && !this.disposed; next = live.pending, live.pending = null) await this.liveSet(next);
    } finally {
      live.busy = false;
    }
  }

  async liveSet(buffer) {
    const { header, payload } = unpackMessage(buffer);
    if (this.live.resync) {
      header.resync = true;
      this.live.resync = false;
    }
    showSpread(header);
    const seq = await this.scene.liveSet(header, splitPayload(payload, header.sizes));
    if (seq === null) return; // stale cameras: the last complete set stays on show
    this.live.seq = seq;
    this.live.captured = header.captured ?? null;
    this.show();
  }

  /** An error the socket sent: nothing of this view's (it sends no viewpoints). */
  failed() {}

  /** The quality level that runs (or "custom": a switch differs from it) and the one asked for. */
  quality() {
    return { runs: this.page.controls.levelRun(this.level), asked: this.page.controls.quality };
  }

  renderText(header) {
    return `${header.render_ms.toFixed(1)} ms on this GPU`;
  }

  dispose() {
    this.disposed = true;
    this.ready = false;
    if (this.scene) this.scene.dispose();
  }
}
