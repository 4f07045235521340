// The photo-consistency passes (workers/sweep/lanes.py, kernels.py): the sweep's sums for four planes at a
// time (what the window aggregation works on), and the per-pixel winner-take-all search on each pixel's own
// variance (aggregation "none", and the fine level after a coarse one).
import { bindTextures, drawFullscreen } from "./gl.js";
import { setRigUniforms } from "./planes.js";

export const SHADERS = ["fullscreen.vert", "rig.glsl", "refine.glsl", "sweep.frag", "search.frag"];
export const PLANES_PER_PASS = 4;

/** Use ``prog`` with the sweep's rig, planes and vote uniforms set (a program without some ignores them). */
export function rigPass(gl, prog, sweep) {
  gl.useProgram(prog.program);
  setRigUniforms(gl, prog, sweep.geometry, sweep.cameras, sweep.hull);
  const u = prog.uniforms;
  gl.uniform1f(u.uS0, sweep.planes.s0);
  gl.uniform1f(u.uDs, sweep.planes.ds);
  gl.uniform1i(u.uPlanes, sweep.planes.count);
  gl.uniform1i(u.uMinViews, sweep.minViews);
}

/** The plane window uniforms of refine.glsl: after the coarse level ``refine`` ({ coarse: its resolve output,
 * margin }) or every plane (null). ``placeholder`` (any 2D texture) fills the unused sampler: a sampler left on a
 * unit that holds another sampler type makes the draw fail. Returns the texture to bind to uCoarse. */
function setWindow(gl, prog, refine, placeholder) {
  gl.uniform1i(prog.uniforms.uRefine, refine ? 1 : 0);
  gl.uniform1i(prog.uniforms.uMargin, refine ? refine.margin : 0);
  return refine ? refine.coarse : placeholder;
}

/** Sums (squared deviations, votes) of planes first .. first + 3 into ``target`` (a two-texture framebuffer), of
 * the planes in each pixel's window when sweep.refine is given (the fine level of a cost volume).
 * sweep: { geometry, cameras, planes, hull, minViews, frames, placeholder, refine }. */
export function sweepPlanes(gl, prog, sweep, first, target) {
  rigPass(gl, prog, sweep);
  const coarse = setWindow(gl, prog, sweep.refine, sweep.placeholder);
  bindTextures(gl, prog, { uImages: sweep.frames.images, uSilhouettes: sweep.frames.silhouettes, uCoarse: coarse });
  gl.uniform1i(prog.uniforms.uFirst, first);
  drawFullscreen(gl, target);
}

/** Winner-take-all over every plane, or (coarse given: a resolve output of the half-size level) over the
 * planes within ``margin`` of the coarse choices around each pixel's parent, into ``target``. */
export function searchPixels(gl, prog, sweep, coarse, margin, target) {
  rigPass(gl, prog, sweep);
  const tex = setWindow(gl, prog, coarse ? { coarse, margin } : null, sweep.placeholder);
  bindTextures(gl, prog, { uImages: sweep.frames.images, uSilhouettes: sweep.frames.silhouettes, uCoarse: tex });
  drawFullscreen(gl, target);
}
