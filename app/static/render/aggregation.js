// Window aggregation (workers/sweep/costs.py): the sweep's sums box-filtered over a (2r + 1)^2 window, their
// ratio the windowed variance, and the winner over all planes with its sub-plane parabola. The planes stream
// through four at a time, so no cost volume is stored: a running state keeps the best plane, its cost and
// the costs of the planes either side.
import { bindTextures, drawFullscreen } from "./gl.js";
import { PLANES_PER_PASS, sweepPlanes } from "./cost.js";

export const SHADERS = ["fullscreen.vert", "boxrows.frag", "winner.frag", "resolve.frag"];

/**
 * The windowed winner of every pixel into ``work.depth`` (resolve output: inverse depth, plane, offset, cost).
 * work: the size's textures and framebuffers (renderer.Workspace); programs: {sweep, boxrows, winner, resolve}.
 */
export function windowedWinner(gl, programs, sweep, radius, subplane, work, out) {
  let state = 0;
  for (let first = 0; first < sweep.planes.count; first += PLANES_PER_PASS) {
    rowSums(gl, programs, sweep, first, radius, work);
    const win = programs.winner;
    gl.useProgram(win.program);
    bindTextures(gl, win, {
      uSsdRows: work.ssdRows, uVotesRows: work.votesRows, uVotes: work.votes,
      uStateA: work.stateA[state], uStateB: work.stateB[state],
    });
    gl.uniform1i(win.uniforms.uRadius, radius);
    gl.uniform1i(win.uniforms.uFirst, first);
    gl.uniform1i(win.uniforms.uPlanes, sweep.planes.count);
    state = 1 - state;
    drawFullscreen(gl, work.stateTargets[state]);
  }
  resolve(gl, programs.resolve, sweep.planes, subplane, work.stateA[state], out);
}

/** The sweep's sums of planes first .. first + 3 into work.ssd / work.votes and their row sums over 2 radius + 1
 * pixels into work.ssdRows / work.votesRows (the first half of the window sums). */
export function rowSums(gl, programs, sweep, first, radius, work) {
  sweepPlanes(gl, programs.sweep, sweep, first, work.sumsTarget);
  const rows = programs.boxrows;
  gl.useProgram(rows.program);
  bindTextures(gl, rows, { uSsd: work.ssd, uVotes: work.votes });
  gl.uniform1i(rows.uniforms.uRadius, radius);
  drawFullscreen(gl, work.rowsTarget);
}

/** The chosen plane and its sub-plane offset (resolve.frag) from a winner state texture into ``out``. */
export function resolve(gl, prog, planes, subplane, state, out) {
  gl.useProgram(prog.program);
  bindTextures(gl, prog, { uStateA: state });
  gl.uniform1f(prog.uniforms.uS0, planes.s0);
  gl.uniform1f(prog.uniforms.uDs, planes.ds);
  gl.uniform1i(prog.uniforms.uPlanes, planes.count);
  gl.uniform1i(prog.uniforms.uSubplane, subplane ? 1 : 0);
  drawFullscreen(gl, out);
}
