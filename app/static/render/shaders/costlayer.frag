#version 300 es
// A layer of the cost volume (workers/sweep/costs.py windowed_variance, robust_cost) for four planes: the column
// half of the window sums and their ratio, the windowed variance; for semi-global aggregation (uRobust) its square
// root capped at uCap colour levels. A plane the pixel did not vote for itself, and a padding plane past the last, is no
// candidate: BIG (the server's inf).
precision highp float;
precision highp int;
uniform highp sampler2D uSsdRows;    // row sums of the squared deviations
uniform highp sampler2D uVotesRows;  // row sums of the votes
uniform highp sampler2D uVotes;      // the pixel's own votes
uniform int uRadius;
uniform int uFirst;
uniform int uPlanes;
uniform float uCap;
uniform bool uRobust;
out vec4 oCost;
#include "window.glsl"

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec4 num, den;
  columnSums(uSsdRows, uVotesRows, p, uRadius, num, den);
  vec4 own = texelFetch(uVotes, p, 0);
  vec4 cost;
  for (int k = 0; k < 4; k++) {
    if (!(uFirst + k < uPlanes && own[k] > 0.0)) {
      cost[k] = BIG;
      continue;
    }
    float variance = num[k] / den[k];
    cost[k] = uRobust ? min(sqrt(variance), uCap) : variance;
  }
  oCost = cost;
}
