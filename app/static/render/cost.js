// The photo-consistency passes (workers/sweep/lanes.py, kernels.py): the sweep's sums for four planes at a
// time (what the window aggregation works on), and the per-pixel winner-take-all search on each pixel's own
// variance (aggregation "none", and the fine level after a coarse one).
import { target } from "./gl.js";
import { Pass } from "./pass.js";
import { planeUniforms, rigUniforms } from "./planes.js";

export const SHADERS = ["fullscreen.vert", "rig.glsl", "refine.glsl", "sweep.frag", "search.frag"];
export const PLANES_PER_PASS = 4;

/** The plane window uniforms of refine.glsl: after the coarse level ``refine`` ({ coarse: its resolve output,
 * margin }), else every plane (null). */
function windowUniforms(refine) {
  return { uRefine: refine !== null, uMargin: refine ? refine.margin : 0, uCoarse: refine ? refine.coarse : null };
}

export class Cost {
  /** The passes, compiled with the renderer's ``defines`` (N_CAM, the server's rules). */
  constructor(gl, defines) {
    this.gl = gl;
    this.sums = new Pass(gl, "sweep.frag", { defines });
    this.search = new Pass(gl, "search.frag", { defines });
  }

  /** Sums (squared deviations, votes) of planes first .. first + 3 into ``ssd`` and ``votes`` (2D textures), of
   * the planes in each pixel's window when sweep.refine is given (the fine level of a cost volume).
   * sweep: { geometry, cameras, planes, hull, minViews, frames, refine }. */
  planeSums(sweep, first, ssd, votes) {
    this.sums.set({ ...rigUniforms(sweep), ...planeUniforms(sweep.planes), ...windowUniforms(sweep.refine),
      uMinViews: sweep.minViews, uFirst: first });
    this.sums.draw(target(this.gl, [ssd, votes]));
  }

  /** Winner-take-all over every plane, or (coarse given: a resolve output of the half-size level) over the
   * planes within ``margin`` of the coarse choices around each pixel's parent, into ``out`` (a 2D texture). */
  searchPixels(sweep, coarse, margin, out) {
    this.search.set({ ...rigUniforms(sweep), ...planeUniforms(sweep.planes),
      ...windowUniforms(coarse ? { coarse, margin } : null), uMinViews: sweep.minViews });
    this.search.draw(target(this.gl, [out]));
  }

  dispose() {
    this.sums.dispose();
    this.search.dispose();
  }
}
