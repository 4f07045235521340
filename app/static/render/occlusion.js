// Half-occlusions and visibility (workers/sweep/occlusion.py, visibility.py) as WebGL2 passes: the cross-view check
// of the planes against the cost volume they were chosen on, the background fill of the pixels it rejects, and the
// per-camera z-buffers of the view's own surface for visibility-aware colour.
//
// Both camera-side steps scatter: every hypothesis (virtual pixel, plane) into each camera for the check, every
// pixel of the view into each camera for the z-buffers. WebGL2 has no scattered writes or atomics, so each is a
// draw of points (one vertex per hypothesis or pixel, no attributes: the vertex shader decodes gl_VertexID) into
// one camera's layer, the depth test keeping the least value per camera pixel: the fragment writes that value
// (a cost, a depth) as its depth, scaled by a power of two (exact in a float32 depth buffer), and ties keep the
// first drawn, the server's order. 320x240 with 48 planes and 10 cameras is 37 M points a frame.
import { depthBuffer, release, target, texture2d, textureArray } from "./gl.js";
import { Pass } from "./pass.js";
import { planeUniforms, rigUniforms } from "./planes.js";

export const SHADERS = ["rig.glsl", "fullscreen.vert", "winners.vert", "winners.frag", "confirm.frag", "fill.frag",
  "splat.vert", "splat.frag"];
const COST_SCALE = 2 ** -40;  // costs (colour levels squared, semi-global totals) below 2^40 stay under 1
const DEPTH_SCALE = 2 ** -40; // depths along a camera's axis likewise
const FAR = 3.4e38;           // an empty z-buffer pixel: nothing of the view in front

/** Whether the rejected pixels are filled along the rows: the cameras spread at least as far along the view's x
 * axis as along its y axis (workers/sweep/occlusion.py fill_along_rows). */
export function fillAlongRows(virtual, centres) {
  const R = virtual.R;
  const C = virtual.center;
  const xs = [];
  const ys = [];
  for (const c of centres) {
    const d = [c[0] - C[0], c[1] - C[1], c[2] - C[2]];
    xs.push(R[0] * d[0] + R[1] * d[1] + R[2] * d[2]);
    ys.push(R[3] * d[0] + R[4] * d[1] + R[5] * d[2]);
  }
  const ptp = (a) => Math.max(...a) - Math.min(...a);
  return ptp(xs) >= ptp(ys);
}

/** Per-camera scatter targets: a colour layer and a shared float32 depth buffer of the largest camera's size. */
class CameraTargets {
  constructor(gl, w, h, n, kind) {
    Object.assign(this, { gl, width: w, height: h, count: n, kind });
    this.colour = textureArray(gl, kind, w, h, n);
    this.depth = depthBuffer(gl, w, h);
  }

  /** Draw ``pass``'s ``count`` points into camera i's layer, cleared to ``clear`` (RGBA) and an empty depth,
   * keeping the least depth per pixel. */
  scatter(pass, i, count, clear) {
    const gl = this.gl;
    const into = target(gl, [{ tex: this.colour, layer: i }], this.depth);
    gl.bindFramebuffer(gl.FRAMEBUFFER, into.fb);
    gl.clearBufferfv(gl.COLOR, 0, clear);
    gl.clearBufferfv(gl.DEPTH, 0, [1.0]);
    gl.enable(gl.DEPTH_TEST);
    gl.depthFunc(gl.LESS);
    pass.drawPoints(into, count);
    gl.disable(gl.DEPTH_TEST);
  }

  dispose() {
    release(this.gl, this.colour, this.depth);
  }
}

export class Occlusions {
  /** The passes, compiled with the renderer's ``defines`` (N_CAM, the server's rules). */
  constructor(gl, defines) {
    this.gl = gl;
    this.winners = new Pass(gl, "winners.frag", { vertex: "winners.vert", defines });
    this.confirm = new Pass(gl, "confirm.frag", { defines });
    this.fillPass = new Pass(gl, "fill.frag");
    this.splat = new Pass(gl, "splat.frag", { vertex: "splat.vert", defines });
    const [, largest] = gl.getParameter(gl.ALIASED_POINT_SIZE_RANGE);
    this.pointsOk = largest >= 2;
    this.cameraTargets = new Map(); // "w h n kind" -> CameraTargets
    this.view = null; // { width, height, rejected, filled, targets } at the view's size
  }

  targetsFor(cameras, kind) {
    const w = Math.max(...cameras.map((c) => c.width));
    const h = Math.max(...cameras.map((c) => c.height));
    const key = `${w} ${h} ${cameras.length} ${kind}`;
    if (!this.cameraTargets.has(key)) {
      for (const [k, t] of this.cameraTargets) { // another source factor's: not needed again soon
        if (t.kind !== kind) continue;
        t.dispose();
        this.cameraTargets.delete(k);
      }
      this.cameraTargets.set(key, new CameraTargets(this.gl, w, h, cameras.length, kind));
    }
    return this.cameraTargets.get(key);
  }

  viewTextures(w, h) {
    if (!this.view || this.view.width !== w || this.view.height !== h) {
      this.releaseView();
      this.view = { width: w, height: h, rejected: texture2d(this.gl, "r8", w, h),
        filled: texture2d(this.gl, "rgba32f", w, h) };
    }
    return this.view;
  }

  /**
   * The occlusion fill (workers/sweep/renderer.py _fill_occlusions) of ``depth`` in place: the pixels whose plane
   * fewer than sweep.minViews cameras' own choices from ``volume`` confirm take the farther neighbouring depth along
   * the line (``rows``, else the columns). depth: a resolve output of the view's size (a 2D texture); volume: the
   * array texture the planes were chosen on; sweep: the renderer's sweep ({ geometry, cameras, planes, minViews }).
   */
  fill(sweep, volume, depth, rows) {
    const gl = this.gl;
    const { width: w, height: h } = depth;
    const winners = this.targetsFor(sweep.cameras, "rg32f");
    this.winners.set({ ...rigUniforms(sweep), ...planeUniforms(sweep.planes), uVolume: volume, uWidth: w,
      uTarget: [winners.width, winners.height], uDepthScale: COST_SCALE });
    sweep.cameras.forEach((_, i) => {
      this.winners.set({ uCamera: i });
      winners.scatter(this.winners, i, w * h * sweep.planes.count, [-1, 0, 0, 0]);
    });
    const view = this.viewTextures(w, h);
    this.confirm.set({ ...rigUniforms(sweep), uS0: sweep.planes.s0, uDs: sweep.planes.ds, uMinViews: sweep.minViews,
      uDepth: depth, uWinners: winners.colour });
    this.confirm.draw(target(gl, [view.rejected]));
    this.fillPass.set({ uDepth: depth, uRejected: view.rejected, uRows: rows });
    this.fillPass.draw(target(gl, [view.filled]));
    gl.bindFramebuffer(gl.READ_FRAMEBUFFER, target(gl, [view.filled]).fb);
    gl.bindFramebuffer(gl.DRAW_FRAMEBUFFER, target(gl, [depth]).fb);
    gl.blitFramebuffer(0, 0, w, h, 0, 0, w, h, gl.COLOR_BUFFER_BIT, gl.NEAREST);
    gl.bindFramebuffer(gl.READ_FRAMEBUFFER, null);
    gl.bindFramebuffer(gl.DRAW_FRAMEBUFFER, null);
  }

  /** The z-buffers of the view's surface (``depth``, a resolve output texture) in every camera: an array texture,
   * layer i camera i's nearest depth (m along its axis) per pixel, FAR where nothing of the view lies. */
  zbuffers(sweep, depth) {
    const targets = this.targetsFor(sweep.cameras, "r32f");
    this.splat.set({ ...rigUniforms(sweep), uDepth: depth, uTarget: [targets.width, targets.height],
      uDepthScale: DEPTH_SCALE });
    sweep.cameras.forEach((_, i) => {
      this.splat.set({ uCamera: i });
      targets.scatter(this.splat, i, depth.width * depth.height, [FAR, 0, 0, 0]);
    });
    return targets.colour;
  }

  releaseView() {
    const v = this.view;
    if (v) release(this.gl, v.rejected, v.filled);
  }

  dispose() {
    for (const t of this.cameraTargets.values()) t.dispose();
    this.releaseView();
    for (const p of [this.winners, this.confirm, this.fillPass, this.splat]) p.dispose();
  }
}
