// The colour pass: each pixel coloured from the rig cameras at its chosen depth by one of the five weightings
// (workers/sweep/weighting.py; the formulas are in shaders/shade.frag), D_bnd derived from the rig when not given.
import { bindTextures, drawFullscreen } from "./gl.js";
import { glMatrices, setRigUniforms } from "./planes.js";

export const SHADERS = ["fullscreen.vert", "rig.glsl", "shade.frag"];

/** Shade ``depth`` (a resolve output) of ``virtual`` into work.shadeTarget (colour, regions) by ``weighting``
 * ({ method: its code (the render block's rules.codes.method), dBnd, k, globalCamera, fill: RGB }). ``visibility``:
 * { zbuffers (Occlusions.zbuffers), tolerance, filledOnly } for visibility-aware colour (at every pixel, or with
 * filledOnly at the occlusion fill's pixels only), else null; ``placeholderArray`` (any array texture) fills its
 * sampler without. */
export function shade(gl, prog, sweep, virtual, centres, depth, weighting, target, visibility, placeholderArray) {
  gl.useProgram(prog.program);
  setRigUniforms(gl, prog, sweep.geometry, sweep.cameras, sweep.hull);
  bindTextures(gl, prog, {
    uImages: sweep.frames.images, uSilhouettes: sweep.frames.silhouettes, uDepth: depth,
    uZbuf: visibility ? visibility.zbuffers : placeholderArray,
  });
  const u = prog.uniforms;
  gl.uniformMatrix3fv(u.uG, false, glMatrices([sweep.geometry.G]));
  gl.uniform3fv(u.uEye, Float32Array.from(virtual.center));
  gl.uniform3fv(u["uCentres[0]"], Float32Array.from(centres.flat()));
  gl.uniform1i(u.uMethod, weighting.method);
  gl.uniform1f(u.uDBnd, weighting.dBnd ?? 1.0);
  gl.uniform1i(u.uK, weighting.k);
  gl.uniform1i(u.uGlobal, weighting.globalCamera);
  gl.uniform3fv(u.uFill, Float32Array.from(weighting.fill));
  gl.uniform1i(u.uVisibility, visibility ? 1 : 0);
  gl.uniform1f(u.uVisScale, 1 + (visibility ? visibility.tolerance : 0));
  gl.uniform1i(u.uFilledOnly, visibility && visibility.filledOnly ? 1 : 0);
  drawFullscreen(gl, target);
}
