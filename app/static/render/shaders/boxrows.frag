#version 300 es
// First half of the window sums (workers/sweep/costs.py box_sum): along the rows, pixels beyond the border
// counting as 0. Two inputs at once (the squared deviations and the votes of four planes).
precision highp float;
precision highp int;
uniform highp sampler2D uSsd;
uniform highp sampler2D uVotes;
uniform int uRadius;
layout(location = 0) out vec4 oSsd;
layout(location = 1) out vec4 oVotes;

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  int w = textureSize(uSsd, 0).x;
  vec4 a = vec4(0.0);
  vec4 b = vec4(0.0);
  for (int d = -uRadius; d <= uRadius; d++) {
    int x = p.x + d;
    if (x < 0 || x >= w) continue;
    a += texelFetch(uSsd, ivec2(x, p.y), 0);
    b += texelFetch(uVotes, ivec2(x, p.y), 0);
  }
  oSsd = a;
  oVotes = b;
}
