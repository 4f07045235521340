#version 300 es
// The background fill (workers/sweep/occlusion.py background_fill): each maximal run of rejected pixels along the
// line (the row, or with uRows false the column) takes the plane and sub-plane offset of the farther (smaller
// inverse depth) of the two pixels just outside the run that have a depth, the one before the run on a tie; of the
// one when only one has; its own when neither has. Every rejected pixel gets a NaN cost (the server's mark of the
// pixels the fill was given, RenderResult.filled).
precision highp float;
precision highp int;
uniform highp sampler2D uDepth;     // resolve output: (inverse depth or 0, plane or -1, offset, cost)
uniform highp sampler2D uRejected;  // confirm.frag's output (.x 1: rejected)
uniform bool uRows;
out vec4 oDepth;

bool rejected(ivec2 q) {
  return texelFetch(uRejected, q, 0).x > 0.5;
}

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec4 own = texelFetch(uDepth, p, 0);
  oDepth = own;
  if (!rejected(p)) return;
  ivec2 step = uRows ? ivec2(1, 0) : ivec2(0, 1);
  int along = uRows ? p.x : p.y;
  int count = uRows ? textureSize(uDepth, 0).x : textureSize(uDepth, 0).y;
  int before = along - 1;
  while (before >= 0 && rejected(p + (before - along) * step)) before--;
  int after = along + 1;
  while (after < count && rejected(p + (after - along) * step)) after++;
  float sBest = 3.4e38;
  vec4 src = own;
  for (int k = 0; k < 2; k++) {
    int at = k == 0 ? before : after;
    if (at < 0 || at >= count) continue;
    vec4 d = texelFetch(uDepth, p + (at - along) * step, 0);
    if (d.y < 0.0) continue;
    if (d.x < sBest) {  // the inverse depth of its plane and offset
      sBest = d.x;
      src = d;
    }
  }
  oDepth = vec4(src.xyz, uintBitsToFloat(0x7fc00000u));
}
