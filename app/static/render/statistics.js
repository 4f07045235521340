// What the chosen depths say about the view (workers/sweep/renderer.py: the median depth behind the automatic D_bnd,
// the inverse-depth range of the depth overlay, the coverage): read back from the GPU, every pixel up to 320 x 240,
// else an even grid of about that many (sample.frag). The readback is the only sync point of a render.
import { readFloat, release, target, texture2d } from "./gl.js";
import { Pass } from "./pass.js";
import { median } from "./rig.js";

export const SHADERS = ["fullscreen.vert", "sample.frag"];
const SAMPLES = 320 * 240; // depth samples read back (every pixel up to this size)

export class DepthStatistics {
  constructor(gl) {
    this.gl = gl;
    this.pass = new Pass(gl, "sample.frag");
    this.grid = null; // { width, height, stride, samples } of the last view size
  }

  /** Of ``depth`` (a resolve output, 2D texture): { median (m, NaN without a surface), minInverse, maxInverse
   * (1/m), found (any surface), coverage (share of the pixels with one) }. */
  of(depth) {
    const grid = this.gridFor(depth.width, depth.height);
    let values;
    if (grid.stride === 1) {
      values = readFloat(this.gl, depth, 4);
    } else {
      this.pass.set({ uDepth: depth, uStride: grid.stride });
      this.pass.draw(target(this.gl, [grid.samples]));
      values = readFloat(this.gl, grid.samples, 4);
    }
    const depths = [];
    let minInverse = Infinity;
    let maxInverse = -Infinity;
    const n = values.length / 4;
    for (let i = 0; i < n; i++) {
      const s = values[4 * i];
      if (s > 0) {
        depths.push(Math.fround(1 / s));
        minInverse = Math.min(minInverse, s);
        maxInverse = Math.max(maxInverse, s);
      }
    }
    return { median: depths.length ? median(depths) : NaN, minInverse, maxInverse, found: depths.length > 0,
      coverage: depths.length / n };
  }

  gridFor(w, h) {
    if (!this.grid || this.grid.width !== w || this.grid.height !== h) {
      this.dispose(false);
      const stride = Math.max(1, Math.ceil(Math.sqrt((w * h) / SAMPLES)));
      const samples = stride === 1 ? null : texture2d(this.gl, "rgba32f", Math.ceil(w / stride), Math.ceil(h / stride));
      this.grid = { width: w, height: h, stride, samples };
    }
    return this.grid;
  }

  dispose(all = true) {
    if (this.grid) release(this.gl, this.grid.samples);
    this.grid = null;
    if (all) this.pass.dispose();
  }
}
