#version 300 es
// The cross-view check's second half (workers/sweep/occlusion.py confirmations): a camera confirms a pixel's plane
// when the winner of the camera pixel nearest to where it sees the pixel's point (at the plane, without the
// sub-plane offset) is the pixel itself or a virtual pixel within CONFIRM_TOLERANCE_PX (the server's, defined at
// compile time) of it on each axis. Writes 1 where the pixel has a plane and fewer than uMinViews cameras confirm it
// (to be filled), else 0.
precision highp float;
precision highp int;
precision highp sampler2DArray;
#include "rig.glsl"
uniform highp sampler2D uDepth;         // resolve output (.y: plane or -1)
uniform highp sampler2DArray uWinners;  // per camera: (winning virtual pixel or -1, its cost)
uniform float uS0;
uniform float uDs;
uniform int uMinViews;
out vec4 oRejected;

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  int j = int(texelFetch(uDepth, p, 0).y);
  oRejected = vec4(0.0);
  if (j < 0) return;
  int width = textureSize(uDepth, 0).x;
  int n = 0;
  for (int i = 0; i < N_CAM; i++) {
    vec2 uv;
    if (!projected(i, vec2(p), uS0 + float(j) * uDs, uv) || !insideImage(i, uv)) continue;
    int q = int(texelFetch(uWinners, ivec3(ivec2(floor(uv + 0.5)), i), 0).x);
    if (q >= 0 && abs(q / width - p.y) <= CONFIRM_TOLERANCE_PX && abs(q % width - p.x) <= CONFIRM_TOLERANCE_PX) n++;
  }
  if (n < uMinViews) oRejected = vec4(1.0);
}
