#version 300 es
// Visibility (workers/sweep/visibility.py splat_depths) for camera uCamera: every virtual pixel with a depth is a
// point the camera sees at (u, v); one vertex per pixel, drawn as a 2 x 2 px point over the four pixels its colour
// would be sampled from (floor(u) .. floor(u) + 1, floor(v) .. floor(v) + 1). The depth test keeps the nearest
// (the fragment writes the point's depth along the camera's axis as its depth): the camera's z-buffer of the
// view's own surface.
precision highp float;
precision highp int;
precision highp sampler2DArray;
#include "rig.glsl"
uniform highp sampler2D uDepth;  // resolve output of the view (.x inverse depth, 0: none)
uniform int uCamera;
uniform vec2 uTarget;            // the z-buffer's size (px)
flat out float vDepth;

void main() {
  int width = textureSize(uDepth, 0).x;
  ivec2 p = ivec2(gl_VertexID % width, gl_VertexID / width);
  gl_PointSize = 2.0;
  gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // clipped
  float s = texelFetch(uDepth, p, 0).x;
  vec2 uv;
  float depth;
  if (!(s > 0.0) || !projectedDepth(uCamera, vec2(p), s, uv, depth) || !insideImage(uCamera, uv)) return;
  vec2 corner = floor(uv) + 1.0;  // the shared corner of the four pixels
  gl_Position = vec4(corner / uTarget * 2.0 - 1.0, 0.0, 1.0);
  vDepth = depth;
}
