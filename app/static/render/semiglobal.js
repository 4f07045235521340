// Semi-global aggregation (workers/sweep/costs.py robust_cost, semi_global, winner): the windowed variance of
// every plane as a capped RMS deviation into a cost volume, the scanline paths over it (shaders/sgm.frag says
// how a path runs without compute shaders), and the winner over their sum with its sub-plane parabola.
// Unlike the window aggregation this stores volumes: five of w x h x planes float32 (the cost, the running
// total and the paths, both twice to read one while writing the other), 74 MB at 320x240 with 48 planes.
// The occlusion fill (occlusion.js) needs the volume the planes were chosen on, so with it the window aggregation
// runs here too: the windowed variance into one volume (no paths), and the winner over it.
import { isSoftware, release, target, textureArray } from "./gl.js";
import { PLANES_PER_PASS } from "./cost.js";
import { Pass } from "./pass.js";

export const SHADERS = ["fullscreen.vert", "boxrows.frag", "costlayer.frag", "sgm.frag", "sgmwinner.frag", "resolve.frag"];
export const MAX_PLANES = 128; // the path state lives in registers: 32 groups of four planes
// Lines a draw advances a path (sgm.frag): longer blocks mean fewer draws and more fragments per draw, against
// steps recomputed (a block of n lines costs (n + 1) / 2 steps per pixel). On SwiftShader, where every step is
// CPU time, 2-4 lines were fastest (320x240, 48 planes: 2.3 s a frame against 2.8 s at 8 and 5.2 s at 32); a
// GPU needs many fragments per draw to fill (a 4-line block of a 240-row view is 960) and each draw costs a
// round through the browser's GPU process, so it takes 32 lines: chosen, not yet measured on a GPU.
export const SOFTWARE_BLOCK = 4;
export const GPU_BLOCK = 32;
export const MAX_VOLUME_BYTES = 512e6; // beyond this the browser leaves the volumes' options to the server

/** Bytes of GPU memory the volumes of a w x h level with ``planes`` planes take: five with semi-global ``paths``,
 * else the cost volume alone. */
export function volumeBytes(w, h, planes, paths = true) {
  return (paths ? 5 : 1) * Math.ceil(planes / PLANES_PER_PASS) * 16 * w * h;
}

// The server's order (rows both ways, then down and up the columns for dx = 0, -1, 1), so that the totals add up
// in the same order.
const DIRECTIONS = {
  4: [[1, 0], [-1, 0], [0, 1], [0, -1]],
  8: [[1, 0], [-1, 0], [0, 1], [0, -1], [-1, 1], [-1, -1], [1, 1], [1, -1]],
};

class Volumes {
  /** The cost volume, totals and paths (with ``paths``) for w x h and ``groups`` layers of four planes; ``out``
   * groups a draw of the paths (every draw writes that many layers of a total and of a path). */
  constructor(gl, w, h, groups, out, paths) {
    Object.assign(this, { gl, width: w, height: h, groups, out, paths });
    const volume = () => textureArray(gl, "rgba32f", w, h, groups);
    this.cost = volume();
    if (!paths) return;
    this.total = [volume(), volume()];
    this.path = [volume(), volume()];
  }

  /** The target of layer ``g`` of the cost volume. */
  costTarget(g) {
    return target(this.gl, [{ tex: this.cost, layer: g }]);
  }

  /** The target of draw ``d`` of the paths: its groups of total ``t`` and of path ``s``. */
  pathTarget(t, s, d) {
    const layers = Array.from({ length: this.out }, (_, i) => d * this.out + i);
    const into = (tex) => layers.map((layer) => (layer < this.groups ? { tex, layer } : null));
    return target(this.gl, [...into(this.total[t]), ...into(this.path[s])]);
  }

  get draws() {
    return Math.ceil(this.groups / this.out);
  }

  dispose() {
    release(this.gl, this.cost, ...(this.paths ? [...this.total, ...this.path] : []));
  }
}

export class SemiGlobal {
  /** ``window``: the renderer's WindowAggregation (the window sums and the resolve pass). */
  constructor(gl, window) {
    this.gl = gl;
    this.window = window;
    const buffers = gl.getParameter(gl.MAX_DRAW_BUFFERS);
    this.out = buffers >= 8 ? 4 : 2; // groups per draw: half the attachments take totals, half paths
    this.passes = new Map(); // groups -> { costlayer, sgm, winner } (NG is a compile-time constant)
    this.volumes = new Map(); // "w h groups paths" -> Volumes: the coarse and the fine level's, kept between renders
    this.block = isSoftware(gl) ? SOFTWARE_BLOCK : GPU_BLOCK;
  }

  passesFor(groups) {
    if (!this.passes.has(groups)) {
      const defines = { NG: groups, NOUT: this.out };
      this.passes.set(groups, {
        costlayer: new Pass(this.gl, "costlayer.frag", { defines }),
        sgm: new Pass(this.gl, "sgm.frag", { defines }),
        winner: new Pass(this.gl, "sgmwinner.frag", { defines }),
      });
    }
    return this.passes.get(groups);
  }

  volumesFor(w, h, groups, paths) {
    const key = `${w} ${h} ${groups} ${paths}`;
    if (!this.volumes.has(key)) {
      if (this.volumes.size >= 2) { // a render uses at most two levels: the oldest goes
        const [oldest, v] = this.volumes.entries().next().value;
        v.dispose();
        this.volumes.delete(oldest);
      }
      this.volumes.set(key, new Volumes(this.gl, w, h, groups, this.out, paths));
    }
    return this.volumes.get(key);
  }

  /**
   * The winner of every pixel over a stored cost volume into ``out`` (a 2D texture; resolve output: inverse depth,
   * plane, offset, cost): semi-global (o.aggregation "sgm") or the window's variance ("window"). Returns the volume
   * the planes were chosen on (an array texture of four planes a layer, at least BIG where a plane is no candidate).
   * work: the renderer's Workspace at this size (sums, row sums and states); o: RenderOptions' fields (window,
   * cost_cap, sgm_p1, sgm_p2, sgm_directions, subplane).
   */
  winner(sweep, o, work, out) {
    const P = sweep.planes.count;
    const paths = o.aggregation === "sgm";
    if (paths && P > MAX_PLANES) throw new Error(`semi-global aggregation in the browser takes at most ${MAX_PLANES} planes`);
    const groups = Math.ceil(P / PLANES_PER_PASS);
    const own = this.passesFor(groups);
    const vol = this.volumesFor(work.width, work.height, groups, paths);
    this.costVolume(own.costlayer, sweep, o, work, vol, paths);
    const chosenOn = paths ? vol.total[this.paths(own.sgm, vol, o)] : vol.cost;
    own.winner.set({ uTotal: chosenOn, uPlanes: P });
    own.winner.draw(target(this.gl, [work.stateA[0], work.stateB[0]]));
    this.window.resolve(sweep.planes, o.subplane, work.stateA[0], out);
    return chosenOn;
  }

  /** C = min(sqrt(windowed variance), cost_cap) (``robust``) or the windowed variance, BIG where the pixel did not
   * vote for the plane. */
  costVolume(costlayer, sweep, o, work, vol, robust) {
    for (let g = 0; g < vol.groups; g++) {
      const first = g * PLANES_PER_PASS;
      this.window.rowSums(sweep, first, o.window, work);
      costlayer.set({
        uSsdRows: work.ssdRows, uVotesRows: work.votesRows, uVotes: work.votes, uRadius: o.window, uFirst: first,
        uPlanes: sweep.planes.count, uCap: o.cost_cap, uRobust: robust,
      });
      costlayer.draw(vol.costTarget(g));
    }
  }

  /** Every direction's paths, each added to the running total; returns which total holds the sum. */
  paths(sgm, vol, o) {
    const gl = this.gl;
    const { width: w, height: h } = vol;
    sgm.set({ uP1: o.sgm_p1, uP2: o.sgm_p2 });
    gl.enable(gl.SCISSOR_TEST);
    let total = 0;
    DIRECTIONS[o.sgm_directions].forEach(([dx, dy], d) => {
      sgm.set({ uStep: [dx, dy], uFirstDirection: d === 0 });
      const lines = dx !== 0 ? w : h;
      const forward = (dx !== 0 ? dx : dy) > 0;
      for (let b = 0, first = 0; first < lines; b++, first += this.block) {
        const count = Math.min(this.block, lines - first);
        const start = forward ? first : lines - 1 - first; // the block's first line in the path's order
        const low = forward ? first : lines - first - count;
        if (dx !== 0) gl.scissor(low, 0, count, h);
        else gl.scissor(0, low, w, count);
        const path = b % 2;
        sgm.set({ uStart: start, uCost: vol.cost, uPathIn: vol.path[1 - path], uTotalIn: vol.total[total] });
        for (let draw = 0; draw < vol.draws; draw++) {
          sgm.set({ uGroup: draw * vol.out });
          sgm.draw(vol.pathTarget(1 - total, path, draw));
        }
      }
      total = 1 - total;
    });
    gl.disable(gl.SCISSOR_TEST);
    return total;
  }

  dispose() {
    for (const v of this.volumes.values()) v.dispose();
    for (const p of this.passes.values()) for (const q of Object.values(p)) q.dispose();
  }
}
