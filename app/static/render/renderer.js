// The browser renderer: the server's plane sweep and view-dependent weighting (workers/sweep/renderer.py) as
// WebGL2 passes, from frame sets the server ships once. One instance per rig and canvas.
//
//   const r = await BrowserRenderer.create(gl, hello.render);   // the viewer socket's hello, render block
//   r.useFactor(r.rig.sourceFor(w, h).factor);                   // frames at the size the view needs
//   r.frames.setBackgrounds(bitmap, columns); r.frames.setFrames(bitmap, columns);
//   const info = r.render(orbitCamera(hello.orbit, orbit, fov, w, h), { method: "kojima", planes: 48 });
//   r.frames.setFrames(next, columns); r.render(sameCamera, sameOptions, { hold: true });  // no flicker
//   r.present("none");                                           // to the canvas
//
// Options are the server's RenderOptions: their defaults, choices, the codes the shaders take and the fill's
// visibility rule come in the render block's ``rules`` (workers/streaming/rules.py renderer_rules); what the browser
// does not implement (the truncated cost, coarser depth sampling) raises an Unsupported error so that a viewer can
// ask the server instead.
import { SHADERS as AGGREGATION_SHADERS, WindowAggregation } from "./aggregation.js";
import { Cost, SHADERS as COST_SHADERS } from "./cost.js";
import { FrameSet, SHADERS as FRAME_SHADERS } from "./frames.js";
import { canvasTarget, readBytes, readFloat, release, target, texture2d } from "./gl.js";
import { fillAlongRows, Occlusions, SHADERS as OCCLUSION_SHADERS } from "./occlusion.js";
import { Presenter, SHADERS as OVERLAY_SHADERS } from "./overlays.js";
import { inversePlanes, sweepGeometry } from "./planes.js";
import { Rig } from "./rig.js";
import { MAX_PLANES as SGM_MAX_PLANES, MAX_VOLUME_BYTES, SemiGlobal, SHADERS as SGM_SHADERS, volumeBytes } from "./semiglobal.js";
import { loadShaders } from "./programs.js";
import { DepthStatistics, SHADERS as STATISTICS_SHADERS } from "./statistics.js";
import { Hold } from "./temporal.js";
import { Shading, SHADERS as WEIGHTING_SHADERS } from "./weighting.js";

export class Unsupported extends Error {}

/** Options that only colour a depth: a render that differs from the last in these alone may keep its depth. */
const COLOUR_OPTIONS = ["method", "d_bnd", "k", "visibility", "visibility_tolerance", "fill"];

/** What a render's depth depends on besides the frames: the view, its planes and the depth options. */
function viewSignature(virtual, planes, options) {
  const depthOptions = Object.entries(options).filter(([name]) => !COLOUR_OPTIONS.includes(name));
  return JSON.stringify([virtual.K, virtual.R, virtual.t, virtual.width, virtual.height, planes, depthOptions]);
}

/** Which of the given options the browser cannot render (null when it can): the viewer then asks the server.
 * (The depth search's step is the server's finest: BrowserRenderer.render refuses a coarser subpixel_bits.) */
export function unsupported(options) {
  const o = options;
  if (o.aggregation === "sgm" && o.planes > SGM_MAX_PLANES) return `semi-global aggregation of over ${SGM_MAX_PLANES} planes runs on the server`;
  if (o.consistency !== undefined && o.consistency !== "variance") return "the truncated cost runs on the server";
  return null;
}

/** The shaders' #defines of the server's rules (the render block's ``rules``): each code as KIND_NAME
 * (METHOD_KOJIMA_K 4, OVERLAY_DEPTH 2) and the depth search's constants under their own names (rules.glsl). */
export function ruleDefines(rules) {
  const defines = { ...rules.glsl };
  for (const [kind, codes] of Object.entries(rules.codes)) {
    for (const [name, code] of Object.entries(codes)) defines[`${kind}_${name}`.toUpperCase()] = code;
  }
  return defines;
}

class Workspace {
  /** The textures the passes draw into at w x h (each pass makes its render targets of them: gl.js target). */
  constructor(gl, w, h) {
    Object.assign(this, { gl, width: w, height: h });
    const f = () => texture2d(gl, "rgba32f", w, h);
    this.ssd = f(); this.votes = f(); this.ssdRows = f(); this.votesRows = f();
    this.stateA = [f(), f()]; this.stateB = [f(), f()];
    this.depth = f();
    this.kept = f(); // the last render's resolve output (render swaps it with depth)
    this.spare = f();
    this.colour = texture2d(gl, "rgba8", w, h);
    this.regions = texture2d(gl, "rgba8", w, h);
    this.final = texture2d(gl, "rgba8", w, h);
  }

  dispose() {
    release(this.gl, this.ssd, this.votes, this.ssdRows, this.votesRows, ...this.stateA, ...this.stateB, this.depth,
      this.kept, this.spare, this.colour, this.regions, this.final);
  }
}

export class BrowserRenderer {
  /** A renderer for the hello's ``render`` block (rig geometry, silhouette settings, overlay style). */
  static async create(gl, spec) {
    await loadShaders([...new Set([...COST_SHADERS, ...AGGREGATION_SHADERS, ...WEIGHTING_SHADERS, ...OVERLAY_SHADERS,
      ...FRAME_SHADERS, ...SGM_SHADERS, ...OCCLUSION_SHADERS, ...STATISTICS_SHADERS])]);
    return new BrowserRenderer(gl, spec);
  }

  constructor(gl, spec) {
    this.gl = gl;
    this.spec = spec;
    this.rules = spec.rules;
    this.rig = new Rig(spec);
    const defines = { N_CAM: this.rig.size, PALETTE: spec.style.palette.length, ...ruleDefines(spec.rules) };
    this.defines = defines;
    this.cost = new Cost(gl, defines);
    this.window = new WindowAggregation(gl, this.cost);
    this.semiGlobal = new SemiGlobal(gl, this.window);
    this.occlusions = new Occlusions(gl, defines);
    this.shading = new Shading(gl, defines);
    this.presenter = new Presenter(gl, spec.style, defines);
    this.statistics = new DepthStatistics(gl);
    this.holder = new Hold(gl, defines);
    this.lastView = null; // what the last render was of: render's ``hold`` keeps its depth
    this.factor = null;
    this.frames = null;
    this.work = null;
    this.coarse = null;
    this.last = null;
  }

  /** Work at frames shrunk by ``factor`` (Rig.sourceFor); true when that changed (upload frames again). */
  useFactor(factor) {
    if (factor === this.factor) return false;
    this.factor = factor;
    this.cameras = this.rig.camerasAt(factor);
    if (this.frames) this.frames.dispose();
    this.frames = new FrameSet(this.gl, this.cameras.map((c) => [c.width, c.height]), this.spec.silhouettes,
      this.defines);
    return true;
  }

  workspace(w, h, coarse = false) {
    const key = coarse ? "coarse" : "work";
    if (!this[key] || this[key].width !== w || this[key].height !== h) {
      if (this[key]) this[key].dispose();
      this[key] = new Workspace(this.gl, w, h);
    }
    return this[key];
  }

  /**
   * Render ``virtual`` (a Camera) with ``options`` (RenderOptions' fields): the view in work.colour, its
   * depth in work.depth. Returns { ms, d_bnd, depth_range, depth_found, coverage, planes, visual_hull, held }.
   * ``hold``: where the last render was of the same view with the same planes and depth options on an earlier (or
   * the same) frame set, keep its depth (and fill, and derived D_bnd) wherever the scene stood still since
   * (temporal.js; the server's ``previous``); ``held`` says whether it did.
   */
  render(virtual, options = {}, { hold = false } = {}) {
    const o = this.options(options);
    if (!this.frames) throw new Error("no frames yet: call useFactor and upload a frame set first");
    const t0 = performance.now();
    const gl = this.gl;
    const [near, far] = this.depthRange(virtual, o);
    const planes = inversePlanes(near, far, o.planes);
    const hull = o.visual_hull ?? this.frames.hasSilhouettes;
    if (hull && !this.frames.hasSilhouettes) throw new Error("visual_hull requested, but there are no backgrounds");
    const sweep = { cameras: this.cameras, planes, hull, minViews: o.min_views, frames: this.frames, refine: null };
    const fillOcclusions = o.occlusions === "fill";
    if (fillOcclusions && o.aggregation === "none") {
      throw new Error("occlusions 'fill' checks the planes on a cost volume: use aggregation 'window' or 'sgm'");
    }
    if (fillOcclusions && !this.occlusions.pointsOk) {
      throw new Unsupported("this WebGL draws no 2 px points: the occlusion fill runs on the server");
    }
    const coarseToFine = o.coarse_to_fine && Math.min(virtual.width, virtual.height) >= 8;
    const half = coarseToFine ? virtual.scaled(0.5) : null;
    this.checkVolumes(virtual, half, o, fillOcclusions);
    const work = this.workspace(virtual.width, virtual.height);
    const last = this.lastView;
    this.lastView = null; // until this render is done (one that fails leaves nothing to hold)
    [work.depth, work.kept] = [work.kept, work.depth]; // the last render's depth stays, the new one is drawn apart
    const fine = { ...sweep, geometry: sweepGeometry(virtual, this.cameras) };
    gl.disable(gl.BLEND);
    const volume = this.chooseDepth(sweep, fine, half, o, fillOcclusions, work);
    if (fillOcclusions) this.occlusions.fill(fine, volume, work.depth, fillAlongRows(virtual, this.rig.centres));
    // (the same signature means the same size, so work.kept holds that render's depth; a frame set only counts up)
    const view = { signature: viewSignature(virtual, planes, o), frames: this.frames,
      frameSet: this.frames.changes.frameSet };
    const held = hold && last !== null && last.signature === view.signature && last.frames === this.frames;
    if (held) {
      this.holder.hold(fine, virtual, this.rig.centres, work.depth, work.kept, this.frames.changes, last.frameSet,
        work.spare);
      [work.depth, work.spare] = [work.spare, work.depth];
    }
    const stats = this.statistics.of(work.depth);
    let dBnd = ["kojima", "kojima_k"].includes(o.method) ? (o.d_bnd ?? this.rig.autoDBnd(virtual, stats.median)) : null;
    if (held && o.d_bnd == null && last.dBnd != null && dBnd !== null) dBnd = last.dBnd; // the same viewpoint's
    this.lastView = { ...view, dBnd };
    const scope = this.rules.visibility_scope[JSON.stringify(o.visibility ?? null)][o.occlusions];
    const visibility = scope === "none" ? null : { zbuffers: this.occlusions.zbuffers(fine, work.depth),
      parallax: this.parallax(virtual),
      tolerance: o.visibility_tolerance, filledOnly: scope === "filled" };
    const weighting = { method: this.rules.codes.method[o.method], dBnd, k: o.k,
      globalCamera: this.rig.globalCamera(virtual), fill: [o.fill[2], o.fill[1], o.fill[0]] };
    this.shading.shade(fine, virtual, this.rig.centres, work.depth, weighting, visibility, work.colour, work.regions);
    this.last = { virtual, stats };
    const ms = performance.now() - t0;
    return {
      ms, d_bnd: dBnd, depth_range: [planes.near, planes.far], planes: o.planes, visual_hull: hull,
      depth_found: stats.found ? [1 / stats.maxInverse, 1 / stats.minInverse] : null, coverage: stats.coverage, held,
    };
  }

  /** Per camera, its focal length (px) times its distance from ``virtual``'s centre (m): what a depth difference
   * moves by in its image (workers/sweep/kernels.py unhidden's ``parallax``). */
  parallax(virtual) {
    const v = virtual.center;
    return this.cameras.map((c, i) => {
      const p = this.rig.centres[i];
      return Math.max(c.K[0], c.K[4]) * Math.hypot(p[0] - v[0], p[1] - v[1], p[2] - v[2]);
    });
  }

  /** ``options`` over the server's defaults, checked: an Error for a value that is none of the server's choices,
   * Unsupported for what the browser does not render. */
  options(options) {
    const o = { ...this.rules.defaults, ...options };
    for (const [name, values] of Object.entries(this.rules.choices)) {
      if (!values.includes(o[name])) throw new Error(`${name} must be one of ${values.join(", ")}; got ${o[name]}`);
    }
    const why = unsupported(o) ?? (o.subpixel_bits > 0 && o.subpixel_bits < this.rules.glsl.SEARCH_BITS
      ? `the browser samples the depth search at 1/${2 ** this.rules.glsl.SEARCH_BITS} px only` : null);
    if (why) throw new Unsupported(why);
    return o;
  }

  /** The chosen planes of the view into work.depth: the coarse level first with ``half`` (its camera), then each
   * fine pixel's window of planes, searched per pixel, or with ``keepVolume`` (the occlusion fill) aggregated
   * into a cost volume as the server's fine level then does. Returns that volume (null without). */
  chooseDepth(sweep, fine, half, o, keepVolume, work) {
    if (half) {
      const coarse = this.workspace(half.width, half.height, true);
      this.choose({ ...sweep, geometry: sweepGeometry(half, this.cameras) }, o, coarse);
      if (!keepVolume) {
        this.cost.searchPixels(fine, coarse.depth, o.refine_margin, work.depth);
        return null;
      }
      const refine = { coarse: coarse.depth, margin: o.refine_margin };
      return this.semiGlobal.winner({ ...fine, refine }, o, work, work.depth);
    }
    if (keepVolume) return this.semiGlobal.winner(fine, o, work, work.depth);
    this.choose(fine, o, work);
    return null;
  }

  /** Plane choice by the options' aggregation into work.depth. */
  choose(sweep, o, work) {
    if (o.aggregation === "none") {
      this.cost.searchPixels(sweep, null, 0, work.depth);
    } else if (o.aggregation === "sgm") {
      this.semiGlobal.winner(sweep, o, work, work.depth);
    } else {
      this.window.winner(sweep, o.window, o.subplane, work, work.depth);
    }
  }

  /** Refuse (Unsupported) cost volumes beyond MAX_VOLUME_BYTES: semi-global aggregation keeps five at the level it
   * aggregates (the coarse one with coarse-to-fine), and the occlusion fill keeps the fine level's. */
  checkVolumes(virtual, half, o, fillOcclusions) {
    const levels = [];
    if (o.aggregation === "sgm") levels.push(half ?? virtual);
    if (fillOcclusions && (half || o.aggregation !== "sgm")) levels.push(virtual);
    let bytes = 0;
    for (const level of levels) bytes += volumeBytes(level.width, level.height, o.planes, o.aggregation === "sgm");
    if (bytes > MAX_VOLUME_BYTES) {
      const what = fillOcclusions ? "the occlusion fill's cost volumes" : "semi-global aggregation";
      throw new Unsupported(`${what} of a ${levels.at(-1).width}x${levels.at(-1).height} view with ${o.planes} planes `
        + `needs ${(bytes / 1e6).toFixed(0)} MB of GPU memory (the browser takes up to ${MAX_VOLUME_BYTES / 1e6} MB)`);
    }
  }

  depthRange(virtual, o) {
    let near = o.near;
    let far = o.far;
    if (near === null || far === null) {
      const [autoNear, autoFar] = this.rig.autoDepthRange(virtual);
      near = near ?? autoNear;
      far = far ?? autoFar;
    }
    if (!(near < far)) throw new Error(`needs near < far, got ${near} and ${far}`);
    return [near, far];
  }

  /** Draw the last render with ``overlay`` ("none", "regions", "depth") to the canvas, and keep it in work.final. */
  present(overlay = "none", toCanvas = true) {
    const work = this.work;
    const stats = this.last.stats;
    const range = stats.found ? [stats.minInverse, stats.maxInverse] : [0, 1];
    const code = this.rules.codes.overlay[overlay];
    if (code === undefined) throw new Error(`unknown overlay ${overlay}`);
    this.presenter.present(work, code, range, target(this.gl, [work.final]));
    if (toCanvas) this.presenter.present(work, code, range, canvasTarget(work.width, work.height));
  }

  /** Wait until the GPU has drawn everything asked of it so far (a one-pixel readback of the presented view). */
  finish() {
    const gl = this.gl;
    gl.bindFramebuffer(gl.FRAMEBUFFER, target(gl, [this.work.final]).fb);
    gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(4));
  }

  /** The presented picture: Uint8Array RGBA, width * height * 4, top row first. */
  readImage() {
    return readBytes(this.gl, this.work.final);
  }

  /** The chosen depth: Float32Array (inverse depth or 0, plane or -1, sub-plane offset, cost) per pixel. */
  readDepth() {
    return readFloat(this.gl, this.work.depth, 4);
  }

  dispose() {
    for (const w of [this.work, this.coarse]) if (w) w.dispose();
    if (this.frames) this.frames.dispose();
    for (const part of [this.cost, this.window, this.semiGlobal, this.occlusions, this.shading, this.presenter,
      this.statistics, this.holder]) part.dispose();
  }
}

