#version 300 es
// Winner-take-all on each pixel's own variance (aggregation "none"; workers/sweep/kernels.py sweep_depth):
// over every plane, or, after a coarse level, over the window of planes the coarse choices around the pixel's
// parent allow (workers/sweep/kernels.py refine_windows: their min - margin .. max + margin, radius 1).
// Writes (inverse depth or 0, plane or -1, 0, cost).
precision highp float;
precision highp int;
precision highp sampler2DArray;
#include "rig.glsl"
#include "refine.glsl"
uniform float uS0;
uniform float uDs;
uniform int uPlanes;
uniform int uMinViews;
out vec4 oDepth;

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec2 xy = gl_FragCoord.xy - 0.5;
  int lo, hi;
  planeWindow(p, uPlanes, lo, hi);
  float best = BIG;
  int bj = -1;
  for (int j = lo; j <= hi; j++) {
    vec2 c = consistency(xy, uS0 + float(j) * uDs, uMinViews);
    if (c.y == 0.0) continue;
    float cost = c.x / c.y;
    if (cost < best) {
      best = cost;
      bj = j;
    }
  }
  oDepth = bj < 0 ? vec4(0.0, -1.0, 0.0, BIG) : vec4(uS0 + float(bj) * uDs, float(bj), 0.0, best);
}
