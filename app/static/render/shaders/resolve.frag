#version 300 es
// The chosen plane of each pixel and its sub-plane position: the vertex of the parabola through the costs of
// the planes either side (workers/sweep/costs.py parabola_vertex). Writes (inverse depth or 0, plane or -1,
// offset in planes, cost).
precision highp float;
precision highp int;
uniform highp sampler2D uStateA;
uniform float uS0;
uniform float uDs;
uniform int uPlanes;
uniform bool uSubplane;
out vec4 oDepth;

const float BIG = 1e30;

float parabolaVertex(float c0, float c1, float c2) {
  float den = c0 - 2.0 * c1 + c2;
  if (!(den > 0.0) || c0 >= BIG || c2 >= BIG) return 0.0;
  return clamp(0.5 * (c0 - c2) / den, -0.5, 0.5);
}

void main() {
  vec4 a = texelFetch(uStateA, ivec2(gl_FragCoord.xy), 0);
  int j = int(a.y);
  if (j < 0) {
    oDepth = vec4(0.0, -1.0, 0.0, BIG);
    return;
  }
  float offset = uSubplane && j > 0 && j < uPlanes - 1 ? parabolaVertex(a.z, a.x, a.w) : 0.0;
  oDepth = vec4(uS0 + float(j) * uDs + offset * uDs, float(j), offset, a.x);
}
