// The photo-consistency passes (workers/sweep/lanes.py, kernels.py): the sweep's sums for four planes at a
// time (what the window aggregation works on), and the per-pixel winner-take-all search on each pixel's own
// variance (aggregation "none", and the fine level after a coarse one).
import { bindTextures, drawFullscreen } from "./gl.js";
import { setRigUniforms } from "./planes.js";

export const SHADERS = ["fullscreen.vert", "rig.glsl", "sweep.frag", "search.frag"];
export const PLANES_PER_PASS = 4;

function rigPass(gl, prog, sweep) {
  gl.useProgram(prog.program);
  setRigUniforms(gl, prog, sweep.geometry, sweep.cameras, sweep.hull);
  const u = prog.uniforms;
  gl.uniform1f(u.uS0, sweep.planes.s0);
  gl.uniform1f(u.uDs, sweep.planes.ds);
  gl.uniform1i(u.uPlanes, sweep.planes.count);
  gl.uniform1i(u.uMinViews, sweep.minViews);
}

/** Sums (squared deviations, votes) of planes first .. first + 3 into ``target`` (a two-texture framebuffer).
 * sweep: { geometry, cameras, planes, hull, minViews, frames }. */
export function sweepPlanes(gl, prog, sweep, first, target) {
  rigPass(gl, prog, sweep);
  bindTextures(gl, prog, { uImages: sweep.frames.images, uSilhouettes: sweep.frames.silhouettes });
  gl.uniform1i(prog.uniforms.uFirst, first);
  drawFullscreen(gl, target);
}

/** Winner-take-all over every plane, or (coarse given: a resolve output of the half-size level) over the
 * planes within ``margin`` of the coarse choices around each pixel's parent, into ``target``. Without a coarse
 * level ``placeholder`` (any 2D texture) fills the unused sampler: a sampler left on a unit that holds another
 * sampler type makes the draw fail. */
export function searchPixels(gl, prog, sweep, coarse, margin, target, placeholder) {
  rigPass(gl, prog, sweep);
  bindTextures(gl, prog, {
    uImages: sweep.frames.images, uSilhouettes: sweep.frames.silhouettes, uCoarse: coarse || placeholder,
  });
  gl.uniform1i(prog.uniforms.uRefine, coarse ? 1 : 0);
  gl.uniform1i(prog.uniforms.uMargin, margin);
  drawFullscreen(gl, target);
}
