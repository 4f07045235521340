// Window aggregation (workers/sweep/costs.py): the sweep's sums box-filtered over a (2r + 1)^2 window, their
// ratio the windowed variance, and the winner over all planes with its sub-plane parabola. The planes stream
// through four at a time, so no cost volume is stored: a running state keeps the best plane, its cost and
// the costs of the planes either side.
import { target } from "./gl.js";
import { PLANES_PER_PASS } from "./cost.js";
import { Pass } from "./pass.js";

export const SHADERS = ["fullscreen.vert", "boxrows.frag", "winner.frag", "resolve.frag"];

export class WindowAggregation {
  /** The passes; ``cost``: the renderer's Cost (the sweep's sums). */
  constructor(gl, cost) {
    this.gl = gl;
    this.cost = cost;
    this.rows = new Pass(gl, "boxrows.frag");
    this.winnerPass = new Pass(gl, "winner.frag");
    this.resolvePass = new Pass(gl, "resolve.frag");
  }

  /**
   * The windowed winner of every pixel into ``out`` (a 2D texture; resolve output: inverse depth, plane, offset,
   * cost). work: the size's textures (renderer.Workspace: sums, row sums, states).
   */
  winner(sweep, radius, subplane, work, out) {
    let state = 0;
    for (let first = 0; first < sweep.planes.count; first += PLANES_PER_PASS) {
      this.rowSums(sweep, first, radius, work);
      this.winnerPass.set({
        uSsdRows: work.ssdRows, uVotesRows: work.votesRows, uVotes: work.votes,
        uStateA: work.stateA[state], uStateB: work.stateB[state],
        uRadius: radius, uFirst: first, uPlanes: sweep.planes.count,
      });
      state = 1 - state;
      this.winnerPass.draw(target(this.gl, [work.stateA[state], work.stateB[state]]));
    }
    this.resolve(sweep.planes, subplane, work.stateA[state], out);
  }

  /** The sweep's sums of planes first .. first + 3 into work.ssd / work.votes and their row sums over 2 radius + 1
   * pixels into work.ssdRows / work.votesRows (the first half of the window sums). */
  rowSums(sweep, first, radius, work) {
    this.cost.planeSums(sweep, first, work.ssd, work.votes);
    this.rows.set({ uSsd: work.ssd, uVotes: work.votes, uRadius: radius });
    this.rows.draw(target(this.gl, [work.ssdRows, work.votesRows]));
  }

  /** The chosen plane and its sub-plane offset (resolve.frag) from a winner state texture into ``out``. */
  resolve(planes, subplane, state, out) {
    this.resolvePass.set({ uStateA: state, uS0: planes.s0, uDs: planes.ds, uPlanes: planes.count, uSubplane: subplane });
    this.resolvePass.draw(target(this.gl, [out]));
  }

  dispose() {
    for (const p of [this.rows, this.winnerPass, this.resolvePass]) p.dispose();
  }
}
