// The colour pass: each pixel coloured from the rig cameras at its chosen depth by one of the five weightings
// (workers/sweep/weighting.py; the formulas are in shaders/shade.frag), D_bnd derived from the rig when not given.
import { target } from "./gl.js";
import { Pass } from "./pass.js";
import { viewUniforms } from "./planes.js";

export const SHADERS = ["fullscreen.vert", "rig.glsl", "shade.frag"];

export class Shading {
  /** The colour pass, compiled with the renderer's ``defines`` (N_CAM, the server's rules: METHOD_* codes). */
  constructor(gl, defines) {
    this.gl = gl;
    this.pass = new Pass(gl, "shade.frag", { defines });
  }

  /** Shade ``depth`` (a resolve output) of ``virtual`` into ``colour`` and ``regions`` (2D textures) by
   * ``weighting`` ({ method: its code (the render block's rules.codes.method), dBnd, k, globalCamera, fill: RGB }).
   * ``centres``: the rig cameras' centres; ``visibility``: { zbuffers (Occlusions.zbuffers), parallax (per camera,
   * BrowserRenderer.parallax), tolerance, filledOnly }
   * for visibility-aware colour (at every pixel, or with filledOnly at the occlusion fill's pixels only), else null. */
  shade(sweep, virtual, centres, depth, weighting, visibility, colour, regions) {
    this.pass.set({
      ...viewUniforms(sweep, virtual, centres), uDepth: depth, uMethod: weighting.method,
      uDBnd: weighting.dBnd ?? 1.0, uK: weighting.k, uGlobal: weighting.globalCamera, uFill: weighting.fill,
      uVisibility: visibility !== null,
      uZbuf: visibility ? visibility.zbuffers : null, uVisScale: 1 + (visibility ? visibility.tolerance : 0),
      uParallax: visibility ? visibility.parallax : centres.map(() => 0),
      uFilledOnly: visibility !== null && visibility.filledOnly,
    });
    this.pass.draw(target(this.gl, [colour, regions]));
  }

  dispose() {
    this.pass.dispose();
  }
}
