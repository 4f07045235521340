// Depth planes and the per-camera geometry of a sweep (workers/sweep/renderer.py _geometry, kernels.py):
// planes are uniform in inverse depth between near and far along the virtual axis, plane 0 nearest; for
// virtual pixel (x, y) and inverse depth s camera i sees Q_i (x, y, 1) + s B_i, with Q_i = M_i G,
// B_i = M_i C_v + p_i for P_i = K_i [R_i | t_i] = [M_i | p_i], G = R_v^T K_v^-1 and C_v the virtual centre.
import { mat3 } from "./camera.js";

/** Planes between ``near`` and ``far`` (metres): { s0, ds, count } with inverse depth s_j = s0 + j ds. */
export function inversePlanes(near, far, count) {
  if (!(near > 0 && near < far)) throw new Error(`needs 0 < near < far, got ${near} and ${far}`);
  return { s0: 1 / near, ds: (1 / far - 1 / near) / (count - 1), count, near, far };
}

/** Q (row-major 3x3 per camera), B (3 per camera) and G (row-major 3x3) of ``virtual`` against ``cameras``. */
export function sweepGeometry(virtual, cameras) {
  const G = mat3.mul(mat3.transpose(virtual.R), mat3.inverse(virtual.K));
  const C = virtual.center;
  const Q = [];
  const B = [];
  for (const cam of cameras) {
    const M = mat3.mul(cam.K, cam.R);
    const p = mat3.vec(cam.K, cam.t);
    Q.push(mat3.mul(M, G));
    const mc = mat3.vec(M, C);
    B.push([mc[0] + p[0], mc[1] + p[1], mc[2] + p[2]]);
  }
  return { Q, B, G };
}

/** Column-major Float32Array of row-major 3x3 matrices, as uniformMatrix3fv wants them. */
export function glMatrices(rows) {
  const out = new Float32Array(9 * rows.length);
  rows.forEach((m, k) => out.set(mat3.transpose(m), 9 * k));
  return out;
}

/** The uniforms of rig.glsl for ``sweep`` ({ geometry, cameras, hull, frames, ... }), as every pass that sees the
 * rig takes them. */
export function rigUniforms(sweep) {
  return {
    uQ: glMatrices(sweep.geometry.Q), uB: sweep.geometry.B, uLast: sweep.cameras.map((c) => [c.width - 1, c.height - 1]),
    uHull: sweep.hull, uImages: sweep.frames.images, uSilhouettes: sweep.frames.silhouettes,
  };
}

/** rigUniforms, and what a pass that looks back from the view's pixels at the rig cameras takes besides: each
 * pixel's ray (uG), the view's centre (uEye) and the rig cameras' centres (uCentres, ``centres``). */
export function viewUniforms(sweep, virtual, centres) {
  return { ...rigUniforms(sweep), uG: glMatrices([sweep.geometry.G]), uEye: virtual.center, uCentres: centres };
}

/** The planes' uniforms (inverse depth of plane 0, step, count) of ``planes`` (inversePlanes). */
export function planeUniforms(planes) {
  return { uS0: planes.s0, uDs: planes.ds, uPlanes: planes.count };
}
