#version 300 es
// Second half of the window sums (down the columns), the windowed variance of four planes, and the running
// choice of the best plane over the planes seen so far (workers/sweep/costs.py windowed_variance and winner):
// the lowest cost wins, ties to the nearer plane; the costs of its two neighbouring planes are kept for the
// sub-plane parabola. State A = (best cost, best plane or -1, cost of the plane before it, cost of the plane
// after it); state B.x = cost of the last plane seen.
precision highp float;
precision highp int;
uniform highp sampler2D uSsdRows;    // row sums of the squared deviations
uniform highp sampler2D uVotesRows;  // row sums of the votes
uniform highp sampler2D uVotes;      // the pixel's own votes (a plane it did not vote for is no candidate)
uniform highp sampler2D uStateA;
uniform highp sampler2D uStateB;
uniform int uRadius;
uniform int uFirst;
uniform int uPlanes;
layout(location = 0) out vec4 oStateA;
layout(location = 1) out vec4 oStateB;
#include "window.glsl"

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec4 num, den;
  columnSums(uSsdRows, uVotesRows, p, uRadius, num, den);
  vec4 own = texelFetch(uVotes, p, 0);
  vec4 a = uFirst == 0 ? vec4(BIG, -1.0, BIG, BIG) : texelFetch(uStateA, p, 0);
  float last = uFirst == 0 ? BIG : texelFetch(uStateB, p, 0).x;
  for (int k = 0; k < 4; k++) {
    int j = uFirst + k;
    if (j >= uPlanes) break;
    float cost = own[k] > 0.0 ? num[k] / den[k] : BIG;
    a = keepBest(a, cost, j, last);
    last = cost;
  }
  oStateA = a;
  oStateB = vec4(last, 0.0, 0.0, 0.0);
}
