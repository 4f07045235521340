#version 300 es
// Every uStride-th pixel of a resolve output (its inverse depth): a small readback for the depth statistics
// (median for the automatic D_bnd, range for the depth overlay).
precision highp float;
precision highp int;
uniform highp sampler2D uDepth;
uniform int uStride;
out vec4 oSample;

void main() {
  ivec2 size = textureSize(uDepth, 0);
  ivec2 p = min(ivec2(gl_FragCoord.xy) * uStride, size - 1);
  oSample = vec4(texelFetch(uDepth, p, 0).x, 0.0, 0.0, 0.0);
}
