#version 300 es
// The winner over a stored cost volume (workers/sweep/costs.py winner): the semi-global totals, or the windowed
// variance when the occlusion fill keeps the window's volume. The lowest cost, ties to the nearer plane, and the
// costs of its two neighbouring planes for the sub-plane parabola, in the window winner's state layout (best cost,
// best plane or -1, cost of the plane before it, cost of the plane after it) so that resolve.frag finishes both.
// A plane that is no candidate has a cost of at least BIG.
precision highp float;
precision highp int;
precision highp sampler2DArray;
uniform sampler2DArray uTotal;  // NG layers of four planes: the totals or the costs
uniform int uPlanes;
layout(location = 0) out vec4 oState;
layout(location = 1) out vec4 oUnused;  // the state framebuffer's second target (every drawn target needs an output)
#include "window.glsl"

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec4 a = vec4(BIG, -1.0, BIG, BIG);
  float last = BIG;
  for (int g = 0; g < NG; g++) {
    vec4 c = texelFetch(uTotal, ivec3(p, g), 0);
    for (int k = 0; k < 4; k++) {
      int j = 4 * g + k;
      if (j >= uPlanes) break;
      float cost = min(c[k], BIG);
      a = keepBest(a, cost, j, last);
      last = cost;
    }
  }
  oState = a;
  oUnused = vec4(0.0);
}
