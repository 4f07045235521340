#version 300 es
// A hypothesis at a camera pixel (winners.vert): its cost as the depth (scaled by a power of two into [0, 1), so
// that the depth buffer compares the float32 costs exactly), and which virtual pixel it came from.
precision highp float;
uniform float uDepthScale;
flat in float vPixel;
flat in float vCost;
out vec4 oWinner;  // (virtual pixel y * width + x, cost)

void main() {
  gl_FragDepth = vCost * uDepthScale;
  oWinner = vec4(vPixel, vCost, 0.0, 0.0);
}
