#version 300 es
// A point of the view's surface in a camera (splat.vert): its depth, as the depth (scaled by a power of two into
// [0, 1)) and as the z-buffer's value.
precision highp float;
uniform float uDepthScale;
flat in float vDepth;
out vec4 oDepth;

void main() {
  gl_FragDepth = vDepth * uDepthScale;
  oDepth = vec4(vDepth, 0.0, 0.0, 0.0);
}
