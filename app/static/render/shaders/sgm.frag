#version 300 es
// One block of one scanline direction r of semi-global aggregation (workers/sweep/costs.py semi_global):
//
//   L_r(p, j) = C(p, j) + min(L_r(p-r, j), L_r(p-r, j+-1) + p1, min_k L_r(p-r, k) + p2) - min_k L_r(p-r, k)
//
// WebGL2 has no compute shaders or image stores, so a path cannot run in one invocation. The lines across r
// (columns, or rows when r is vertical) are taken a block at a time, one draw per block: a pixel walks its
// path from the block's first line to itself, starting from L_r at the line before the block (stored by the
// previous draw), so pixels of a block recompute what their neighbours upstream compute, and a frame costs
// lines / block draws per direction instead of one per line. Every invocation computes all NG groups of four
// planes (the minimum over planes needs them) and writes NOUT of them from uGroup on: the total over the
// directions so far plus L_r, and L_r itself for the next block. BIG stands for the server's inf (a plane
// that is no candidate); a path whose previous pixel has no candidate restarts.
precision highp float;
precision highp int;
precision highp sampler2DArray;
uniform sampler2DArray uCost;     // C: NG layers of four planes
uniform sampler2DArray uPathIn;   // L_r as the previous block left it
uniform sampler2DArray uTotalIn;  // the sum of L over the directions before this one
uniform ivec2 uStep;              // r, a step of -1, 0 or 1 along each axis
uniform int uStart;               // the block's first line: x when r.x != 0, else y
uniform bool uFirstDirection;     // no total yet
uniform int uGroup;               // the first group this draw writes
uniform float uP1;
uniform float uP2;
layout(location = 0) out vec4 oTotal0;
layout(location = 1) out vec4 oTotal1;
#if NOUT == 4
layout(location = 2) out vec4 oTotal2;
layout(location = 3) out vec4 oTotal3;
layout(location = 4) out vec4 oPath0;
layout(location = 5) out vec4 oPath1;
layout(location = 6) out vec4 oPath2;
layout(location = 7) out vec4 oPath3;
#else
layout(location = 2) out vec4 oPath0;
layout(location = 3) out vec4 oPath1;
#endif

const float BIG = 1e30;
const float RESTART = 0.5e30;  // a path minimum at least this: the pixel had no candidate

float min4(vec4 v) { return min(min(v.x, v.y), min(v.z, v.w)); }

bool inside(ivec2 s, ivec2 size) { return all(greaterThanEqual(s, ivec2(0))) && all(lessThan(s, size)); }

vec4 path[NG];

// One step of the path at pixel s after a pixel whose minimum was m; returns the new minimum.
float pathStep(ivec2 s, float m) {
  float out_ = BIG * 4.0;
  if (m >= RESTART) {
    for (int g = 0; g < NG; g++) {
      path[g] = texelFetch(uCost, ivec3(s, g), 0);
      out_ = min(out_, min4(path[g]));
    }
    return out_;
  }
  float jump = m + uP2;
  float before = BIG;  // L of the plane before this group's first, from the previous pixel
  for (int g = 0; g < NG; g++) {
    vec4 a = path[g];
    float after = g < NG - 1 ? path[g + 1].x : BIG;
    vec4 best = min(a, vec4(jump));
    best = min(best, vec4(before, a.xyz) + uP1);
    best = min(best, vec4(a.yzw, after) + uP1);
    vec4 v = texelFetch(uCost, ivec3(s, g), 0) + (best - m);
    before = a.w;
    path[g] = v;
    out_ = min(out_, min4(v));
  }
  return out_;
}

vec4 total(ivec2 p, int g) {
  return uFirstDirection ? path[g] : texelFetch(uTotalIn, ivec3(p, g), 0) + path[g];
}

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  ivec2 size = textureSize(uCost, 0).xy;
  int n = uStep.x != 0 ? (p.x - uStart) * uStep.x : (p.y - uStart) * uStep.y;  // steps into the block
  float m = BIG;
  ivec2 q = p - (n + 1) * uStep;
  if (inside(q, size)) {
    for (int g = 0; g < NG; g++) {
      path[g] = texelFetch(uPathIn, ivec3(q, g), 0);
      m = min(m, min4(path[g]));
    }
  }
  for (int t = n; t >= 0; t--) {
    ivec2 s = p - t * uStep;
    m = inside(s, size) ? pathStep(s, m) : BIG;  // a diagonal path may enter the image within the block
  }
  int g0 = min(uGroup, NG - 1);
  int g1 = min(uGroup + 1, NG - 1);
  oTotal0 = total(p, g0); oPath0 = path[g0];
  oTotal1 = total(p, g1); oPath1 = path[g1];
#if NOUT == 4
  int g2 = min(uGroup + 2, NG - 1);
  int g3 = min(uGroup + 3, NG - 1);
  oTotal2 = total(p, g2); oPath2 = path[g2];
  oTotal3 = total(p, g3); oPath3 = path[g3];
#endif
}
