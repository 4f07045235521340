#version 300 es
// The cross-view check's first half (workers/sweep/occlusion.py view_winners) for camera uCamera: every hypothesis
// (virtual pixel, plane) of the cost volume the planes were chosen on is a point that the camera sees at some pixel;
// one vertex per hypothesis, in the server's order (row-major pixels, nearest plane first), drawn as a one-pixel
// point at the camera pixel nearest to where it lands. The depth test keeps the least cost per camera pixel (the
// fragment writes the cost as its depth), ties to the first drawn: the camera's own choice among the hypotheses.
precision highp float;
precision highp int;
precision highp sampler2DArray;
#include "rig.glsl"
uniform highp sampler2DArray uVolume;  // the aggregated cost, four planes a layer (>= BIG: no candidate)
uniform int uCamera;
uniform int uWidth;                    // the virtual view's width
uniform int uPlanes;
uniform float uS0;
uniform float uDs;
uniform vec2 uTarget;                  // the winners target's size (px)
flat out float vPixel;                 // y * width + x of the hypothesis' virtual pixel
flat out float vCost;

void main() {
  int j = gl_VertexID % uPlanes;
  int pixel = gl_VertexID / uPlanes;
  ivec2 p = ivec2(pixel % uWidth, pixel / uWidth);
  gl_PointSize = 1.0;
  gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // clipped: no candidate, or the camera does not see the point
  float cost = texelFetch(uVolume, ivec3(p, j / 4), 0)[j % 4];
  vec2 uv;
  if (!(cost < BIG) || !projected(uCamera, vec2(p), uS0 + float(j) * uDs, uv) || !insideImage(uCamera, uv)) return;
  vec2 q = floor(uv + 0.5);  // the nearest pixel (u >= 0)
  gl_Position = vec4((q + 0.5) / uTarget * 2.0 - 1.0, 0.0, 1.0);
  vPixel = float(pixel);
  vCost = cost;
}
