#version 300 es
// The plane sweep: photo-consistency sums of four consecutive planes (uFirst .. uFirst + 3) per pixel,
// the raw material of the windowed cost (workers/sweep/lanes.py lane_cost_volume); after a coarse level only the
// planes of the pixel's window vote (refine.glsl), as the server's fine level does when it keeps a cost volume.
precision highp float;
precision highp int;
precision highp sampler2DArray;
#include "rig.glsl"
#include "refine.glsl"
uniform float uS0;      // inverse depth of plane 0 (1/m)
uniform float uDs;      // inverse-depth step between planes (< 0: plane 0 is nearest)
uniform int uFirst;
uniform int uPlanes;
uniform int uMinViews;
layout(location = 0) out vec4 oSsd;    // per plane: squared deviations (levels^2)
layout(location = 1) out vec4 oVotes;  // per plane: voting cameras

void main() {
  vec2 xy = gl_FragCoord.xy - 0.5;
  int lo, hi;
  planeWindow(ivec2(gl_FragCoord.xy), uPlanes, lo, hi);
  vec4 ssd = vec4(0.0);
  vec4 votes = vec4(0.0);
  for (int k = 0; k < 4; k++) {
    int j = uFirst + k;
    if (j >= uPlanes) break;
    if (j < lo || j > hi) continue;
    vec2 c = consistency(xy, uS0 + float(j) * uDs, uMinViews);
    ssd[k] = c.x;
    votes[k] = c.y;
  }
  oSsd = ssd;
  oVotes = votes;
}
