#version 300 es
// Winner-take-all on each pixel's own variance (aggregation "none"; workers/sweep/kernels.py sweep_depth):
// over every plane, or, after a coarse level, over the window of planes the coarse choices around the pixel's
// parent allow (workers/sweep/kernels.py refine_windows: their min - margin .. max + margin, radius 1).
// Writes (inverse depth or 0, plane or -1, 0, cost).
precision highp float;
precision highp int;
precision highp sampler2DArray;
#include "rig.glsl"
uniform highp sampler2D uCoarse;  // the coarse level's resolve output (.y: plane or -1)
uniform bool uRefine;             // false: every plane
uniform int uMargin;
uniform float uS0;
uniform float uDs;
uniform int uPlanes;
uniform int uMinViews;
out vec4 oDepth;

const int REFINE_RADIUS = 1;

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec2 xy = gl_FragCoord.xy - 0.5;
  int lo = 0;
  int hi = uPlanes - 1;
  if (uRefine) {
    ivec2 size = textureSize(uCoarse, 0);
    ivec2 parent = min(p / 2, size - 1);
    int mn = uPlanes;
    int mx = -1;
    for (int dy = -REFINE_RADIUS; dy <= REFINE_RADIUS; dy++) {
      for (int dx = -REFINE_RADIUS; dx <= REFINE_RADIUS; dx++) {
        ivec2 q = parent + ivec2(dx, dy);
        if (q.x < 0 || q.y < 0 || q.x >= size.x || q.y >= size.y) continue;
        int v = int(texelFetch(uCoarse, q, 0).y);
        if (v >= 0) {
          mn = min(mn, v);
          mx = max(mx, v);
        }
      }
    }
    lo = max(mn - uMargin, 0);
    hi = mx < 0 ? -1 : min(mx + uMargin, uPlanes - 1);
  }
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
