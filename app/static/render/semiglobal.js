// Semi-global aggregation (workers/sweep/costs.py robust_cost, semi_global, winner): the windowed variance of
// every plane as a capped RMS deviation into a cost volume, the scanline paths over it (shaders/sgm.frag says
// how a path runs without compute shaders), and the winner over their sum with its sub-plane parabola.
// Unlike the window aggregation this stores volumes: five of w x h x planes float32 (the cost, the running
// total and the paths, both twice to read one while writing the other), 74 MB at 320x240 with 48 planes.
// The occlusion fill (occlusion.js) needs the volume the planes were chosen on, so with it the window aggregation
// runs here too: the windowed variance into one volume (no paths), and the winner over it.
import { bindTextures, drawFullscreen, framebuffer, isSoftware, program, release, textureArray } from "./gl.js";
import { resolve, rowSums } from "./aggregation.js";
import { PLANES_PER_PASS } from "./cost.js";

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
  /** The cost volume, totals and paths (with ``paths``) for w x h and ``groups`` layers of four planes, with the
   * framebuffers that write them (``out`` groups a draw: every draw writes that many layers of a total and of a
   * path). */
  constructor(gl, w, h, groups, out, paths) {
    Object.assign(this, { gl, width: w, height: h, groups, out, paths });
    const volume = () => textureArray(gl, "rgba32f", w, h, groups);
    this.cost = volume();
    this.costTargets = Array.from({ length: groups }, (_, g) => framebuffer(gl, [{ tex: this.cost, layer: g }]));
    if (!paths) return;
    this.total = [volume(), volume()];
    this.path = [volume(), volume()];
    // pathTargets[t][s][d]: draw d's groups of total t and path s
    this.pathTargets = [0, 1].map((t) => [0, 1].map((s) => Array.from({ length: Math.ceil(groups / out) }, (_, d) => {
      const layers = Array.from({ length: out }, (_, i) => d * out + i);
      const into = (tex) => layers.map((layer) => (layer < groups ? { tex, layer } : null));
      return framebuffer(gl, [...into(this.total[t]), ...into(this.path[s])]);
    })));
  }

  dispose() {
    release(this.gl, this.cost, ...this.costTargets);
    if (this.paths) release(this.gl, ...this.total, ...this.path, ...this.pathTargets.flat(2));
  }
}

export class SemiGlobal {
  constructor(gl) {
    this.gl = gl;
    const buffers = gl.getParameter(gl.MAX_DRAW_BUFFERS);
    this.out = buffers >= 8 ? 4 : 2; // groups per draw: half the attachments take totals, half paths
    this.programs = new Map(); // groups -> { costlayer, sgm, winner } (NG is a compile-time constant)
    this.volumes = new Map(); // "w h groups paths" -> Volumes: the coarse and the fine level's, kept between renders
    this.block = isSoftware(gl) ? SOFTWARE_BLOCK : GPU_BLOCK;
  }

  programsFor(groups) {
    if (!this.programs.has(groups)) {
      const gl = this.gl;
      const defines = { NG: groups, NOUT: this.out };
      this.programs.set(groups, {
        costlayer: program(gl, "fullscreen.vert", "costlayer.frag", defines),
        sgm: program(gl, "fullscreen.vert", "sgm.frag", defines),
        winner: program(gl, "fullscreen.vert", "sgmwinner.frag", defines),
      });
    }
    return this.programs.get(groups);
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
   * The winner of every pixel over a stored cost volume into ``out`` (a resolve output: inverse depth, plane,
   * offset, cost): semi-global (o.aggregation "sgm") or the window's variance ("window"). Returns the volume the
   * planes were chosen on (an array texture of four planes a layer, at least BIG where a plane is no candidate).
   * programs: the renderer's {sweep, boxrows, resolve}; work: its Workspace at this size (sums, row sums and
   * states); o: RenderOptions' fields (window, cost_cap, sgm_p1, sgm_p2, sgm_directions, subplane).
   */
  winner(programs, sweep, o, work, out) {
    const gl = this.gl;
    const P = sweep.planes.count;
    const paths = o.aggregation === "sgm";
    if (paths && P > MAX_PLANES) throw new Error(`semi-global aggregation in the browser takes at most ${MAX_PLANES} planes`);
    const groups = Math.ceil(P / PLANES_PER_PASS);
    const own = this.programsFor(groups);
    const vol = this.volumesFor(work.width, work.height, groups, paths);
    this.costVolume(programs, own.costlayer, sweep, o, work, vol, paths);
    const chosenOn = paths ? vol.total[this.paths(own.sgm, vol, o)] : vol.cost;
    gl.useProgram(own.winner.program);
    bindTextures(gl, own.winner, { uTotal: chosenOn });
    gl.uniform1i(own.winner.uniforms.uPlanes, P);
    drawFullscreen(gl, work.stateTargets[0]);
    resolve(gl, programs.resolve, sweep.planes, o.subplane, work.stateA[0], out);
    return chosenOn;
  }

  /** C = min(sqrt(windowed variance), cost_cap) (``robust``) or the windowed variance, BIG where the pixel did not
   * vote for the plane. */
  costVolume(programs, costlayer, sweep, o, work, vol, robust) {
    const gl = this.gl;
    for (let g = 0; g < vol.groups; g++) {
      const first = g * PLANES_PER_PASS;
      rowSums(gl, programs, sweep, first, o.window, work);
      gl.useProgram(costlayer.program);
      bindTextures(gl, costlayer, { uSsdRows: work.ssdRows, uVotesRows: work.votesRows, uVotes: work.votes });
      const u = costlayer.uniforms;
      gl.uniform1i(u.uRadius, o.window);
      gl.uniform1i(u.uFirst, first);
      gl.uniform1i(u.uPlanes, sweep.planes.count);
      gl.uniform1f(u.uCap, o.cost_cap);
      gl.uniform1i(u.uRobust, robust ? 1 : 0);
      drawFullscreen(gl, vol.costTargets[g]);
    }
  }

  /** Every direction's paths, each added to the running total; returns which total holds the sum. */
  paths(sgm, vol, o) {
    const gl = this.gl;
    const { width: w, height: h } = vol;
    gl.useProgram(sgm.program);
    const u = sgm.uniforms;
    gl.uniform1f(u.uP1, o.sgm_p1);
    gl.uniform1f(u.uP2, o.sgm_p2);
    gl.enable(gl.SCISSOR_TEST);
    let total = 0;
    DIRECTIONS[o.sgm_directions].forEach(([dx, dy], d) => {
      gl.uniform2i(u.uStep, dx, dy);
      gl.uniform1i(u.uFirstDirection, d === 0 ? 1 : 0);
      const lines = dx !== 0 ? w : h;
      const forward = (dx !== 0 ? dx : dy) > 0;
      for (let b = 0, first = 0; first < lines; b++, first += this.block) {
        const count = Math.min(this.block, lines - first);
        const start = forward ? first : lines - 1 - first; // the block's first line in the path's order
        const low = forward ? first : lines - first - count;
        if (dx !== 0) gl.scissor(low, 0, count, h);
        else gl.scissor(0, low, w, count);
        gl.uniform1i(u.uStart, start);
        const path = b % 2;
        bindTextures(gl, sgm, { uCost: vol.cost, uPathIn: vol.path[1 - path], uTotalIn: vol.total[total] });
        vol.pathTargets[1 - total][path].forEach((target, draw) => {
          gl.uniform1i(u.uGroup, draw * vol.out);
          drawFullscreen(gl, target);
        });
      }
      total = 1 - total;
    });
    gl.disable(gl.SCISSOR_TEST);
    return total;
  }

  dispose() {
    for (const v of this.volumes.values()) v.dispose();
    for (const p of this.programs.values()) for (const q of Object.values(p)) this.gl.deleteProgram(q.program);
  }
}
