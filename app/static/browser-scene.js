// The scene on this machine's GPU for a view the browser renders (local-view.js): the browser renderer
// (render/renderer.js) and the frame sets the server ships once: a recording's as immutable HTTP URLs (the browser's
// cache keeps them), the live stream's over the socket as they arrive.
import { BrowserRenderer } from "./render/renderer.js";

const KEEP_PIXELS = 64e6; // decoded frame-set pixels kept for playback (about 256 MB)

export class BrowserScene {
  /** hello: the view socket's hello with render=browser; gl: the canvas' WebGL2 context; headers: for fetch. */
  static async open(gl, hello, headers) {
    const renderer = await BrowserRenderer.create(gl, hello.render);
    return new BrowserScene(renderer, hello, headers);
  }

  constructor(renderer, hello, headers) {
    Object.assign(this, { renderer, hello, headers });
    this.rig = renderer.rig;
    this.columns = hello.render.atlas_columns;
    this.bitmaps = new Map(); // "factor/frame" -> ImageBitmap, least recently used first
    this.shown = null; // "factor/frame" on the GPU now
    this.bytes = { fetched: 0, sets: 0 };
  }

  /** Make the frames of recording frame ``frame`` (or the latest live set) for a width x height view current on
   * the GPU; resolves once they are. */
  async prepare(frame, width, height) {
    if (this.hello.source === "live") { // live sets come at the cameras' size, decoded here
      if (this.renderer.useFactor(1)) await this.fetchLiveModel();
      return;
    }
    const factor = this.rig.sourceFor(width, height).factor;
    const refactored = this.renderer.useFactor(factor);
    if (refactored) {
      this.shown = null;
      this.renderer.frames.setBackgrounds(await this.atlas(factor, "background"), this.columns);
    }
    const key = `${factor}/${frame}`;
    if (this.shown === key) return;
    const bitmap = await this.atlas(factor, frame);
    if (this.renderer.factor !== factor) return; // the size changed meanwhile: the next prepare loads again
    this.renderer.frames.setFrames(bitmap, this.columns);
    this.shown = key;
  }

  /** The decoded atlas of ``frame`` (an index or "background") at ``factor``: kept, or fetched (HTTP cache first). */
  async atlas(factor, frame) {
    const key = `${factor}/${frame}`;
    if (this.bitmaps.has(key)) {
      const kept = this.bitmaps.get(key);
      this.bitmaps.delete(key);
      this.bitmaps.set(key, kept);
      return kept;
    }
    const f = this.hello.frame_sets;
    const url = new URL(f.url.replace("{frame}", frame), location.href);
    url.searchParams.set("factor", factor);
    url.searchParams.set("format", f.format);
    if (f.format === "jpeg") url.searchParams.set("quality", f.quality);
    const response = await fetch(url, { headers: this.headers });
    if (!response.ok) throw new Error(`frame set ${frame}: HTTP ${response.status}`);
    const blob = await response.blob();
    this.bytes.fetched += blob.size;
    this.bytes.sets += 1;
    const bitmap = await createImageBitmap(blob, { premultiplyAlpha: "none", colorSpaceConversion: "none" });
    this.bitmaps.set(key, bitmap);
    let pixels = [...this.bitmaps.values()].reduce((n, b) => n + b.width * b.height, 0);
    for (const [k, b] of this.bitmaps) {
      if (pixels <= KEEP_PIXELS || this.bitmaps.size <= 2) break;
      pixels -= b.width * b.height;
      b.close();
      this.bitmaps.delete(k);
    }
    return bitmap;
  }

  /** Start the live background model from the server's (none yet: 404, silhouettes come once a background
   * set arrives). */
  async fetchLiveModel() {
    const response = await fetch(new URL(this.hello.live.background_url, location.href), { headers: this.headers });
    if (response.status === 404) return;
    if (!response.ok) throw new Error(`live background: HTTP ${response.status}`);
    const blob = await response.blob();
    this.bytes.fetched += blob.size;
    const bitmap = await createImageBitmap(blob, { premultiplyAlpha: "none", colorSpaceConversion: "none" });
    this.renderer.frames.setLiveModel(bitmap, this.columns);
    bitmap.close();
  }

  /** A live frame set from the socket (its header and one JPEG per camera, rig order): decoded, uploaded and
   * run through the background model. Resolves with the set's seq, or null for a set with stale cameras (their
   * images are not of its instant, and this renderer draws every camera: the last complete set stays shown). */
  async liveSet(header, jpegs) {
    if (header.stale && header.stale.length) return null;
    this.renderer.useFactor(1);
    const bitmaps = await Promise.all(jpegs.map((bytes) => createImageBitmap(new Blob([bytes], { type: "image/jpeg" }),
      { premultiplyAlpha: "none", colorSpaceConversion: "none" })));
    this.bytes.fetched += jpegs.reduce((n, b) => n + b.byteLength, 0);
    this.bytes.sets += 1;
    if (header.resync) await this.fetchLiveModel();
    bitmaps.forEach((b, i) => {
      this.renderer.frames.setCamera(i, b);
      b.close();
    });
    this.renderer.frames.observeLive(header.background, this.hello.live.background_rate);
    this.shown = `live/${header.seq}`;
    return header.seq;
  }

  /** Render ``camera`` with ``options`` and show it with ``overlay``: the renderer's info, ``ms`` the time until
   * the GPU has drawn it (a one-pixel readback waits for it). The same view of a newer frame set (a recording
   * playing, the live stream) keeps its depth where the scene stood still, as the server's viewer does. */
  draw(camera, options, overlay) {
    const t0 = performance.now();
    const info = this.renderer.render(camera, options, { hold: true });
    this.renderer.present(overlay);
    this.renderer.finish();
    return { ...info, ms: performance.now() - t0 };
  }

  dispose() {
    for (const b of this.bitmaps.values()) b.close();
    this.bitmaps.clear();
    this.renderer.dispose();
  }
}
