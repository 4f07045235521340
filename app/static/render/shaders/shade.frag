#version 300 es
// The colour of each virtual pixel at its chosen depth, by one of the five weightings
// (workers/sweep/kernels.py shade, workers/sweep/weighting.py): cameras are compared by the cosine of the
// angle between their ray to the surface point and the virtual ray to it (the paper's Fig. 1). uMethod is one of
// the server's codes (weighting.METHOD_CODES), defined at compile time as METHOD_<NAME>:
//   global: one camera for the whole view (uGlobal), the nearest one where it cannot see the point
//   nearest: the camera of largest cosine (the primary)
//   ulr: the k nearest by angle, w_i = 1 - theta_i / theta_(k+1), normalised
//   kojima: primary and secondary, eqs. 1-6: D12 = cos1 - cos2 >= D_bnd: primary alone, else
//     w1 = (1 + D12 / D_bnd) / 2, w2 = 1 - w1
//   kojima_k: every camera i with D_1i < D_bnd, weight rho(D_1i) = (D_bnd - D) / (D_bnd + D), normalised
// With uVisibility a camera that the view's own surface hides the point from (its z-buffer, splat.vert) takes no
// part, as if its image did not contain the point; all take part where that would leave none. With uFilledOnly too,
// only at the pixels the occlusion fill gave a depth (their cost is NaN: fill.frag), as RenderOptions.visibility
// None does.
// Writes the colour and (regions = cameras with a non-zero weight, primary camera + 1) for the overlays.
precision highp float;
precision highp int;
precision highp sampler2DArray;
#include "rig.glsl"
uniform highp sampler2D uDepth;  // resolve/search output: .x inverse depth (0: no surface)
uniform mat3 uG;                 // virtual ray of pixel (x, y) at unit depth: uG (x, y, 1) = R^T K^-1 (x, y, 1)
uniform vec3 uEye;               // virtual camera centre
uniform vec3 uCentres[N_CAM];    // rig camera centres
uniform int uMethod;
uniform float uDBnd;
uniform int uK;
uniform int uGlobal;
uniform vec3 uFill;              // colour where there is no surface (0..255, RGB)
uniform bool uVisibility;
uniform highp sampler2DArray uZbuf;  // per camera: the nearest depth of the view's surface (m along its axis)
uniform float uVisScale;         // 1 + the visibility tolerance
uniform float uParallax[N_CAM];  // per camera: its focal length (px) x its distance from the view's centre (m)
uniform bool uFilledOnly;        // the visibility test at the filled pixels only
layout(location = 0) out vec4 oColour;
layout(location = 1) out vec4 oRegions;  // r: regions / 255, g: (primary + 1) / 255

// Whether camera i sees the point at uv and ``depth`` past the view's surface: no buffered depth d over the four
// pixels its colour is sampled from with depth > uVisScale x d that has moved against the point by
// MIN_OCCLUDER_PARALLAX_PX or more (uParallax[i] x (1/d - 1/depth) px; workers/sweep/kernels.py unhidden).
bool hides(float d, float depth, float parallax) {
  return depth > d * uVisScale && parallax * (1.0 / d - 1.0 / depth) >= MIN_OCCLUDER_PARALLAX_PX;
}

bool unhidden(int i, vec2 uv, float depth) {
  ivec2 a = ivec2(floor(uv));
  ivec2 b = min(a + 1, ivec2(uLast[i]));  // as bilinear() samples
  ivec2 taps[4] = ivec2[4](a, ivec2(b.x, a.y), ivec2(a.x, b.y), b);
  for (int t = 0; t < 4; t++) {
    if (hides(texelFetch(uZbuf, ivec3(taps[t], i), 0).x, depth, uParallax[i])) return false;
  }
  return true;
}

// Whether the resolve output's cost ``c`` is fill.frag's NaN mark (by its bits: a compiler may assume no NaNs).
bool filledMark(float c) {
  return (floatBitsToUint(c) & 0x7fffffffu) > 0x7f800000u;
}

void main() {
  vec2 xy = gl_FragCoord.xy - 0.5;
  vec4 chosen = texelFetch(uDepth, ivec2(gl_FragCoord.xy), 0);
  float s = chosen.x;
  bool visibility = uVisibility && (!uFilledOnly || filledMark(chosen.w));
  float cosv[N_CAM];
  float theta[N_CAM];
  vec2 uvs[N_CAM];
  int cam[N_CAM];
  bool seen[N_CAM];
  int m = 0;
  if (s > 0.0) {
    vec3 ray = uG * vec3(xy, 1.0) / s;  // from the virtual centre to the surface point
    vec3 toEye = normalize(ray);
    for (int i = 0; i < N_CAM; i++) {
      vec2 uv;
      float depth;
      if (!projectedDepth(i, xy, s, uv, depth)) continue;
      if (!insideImage(i, uv)) continue;
      if (uHull && !inSilhouette(i, uv)) continue;
      vec3 d = normalize(uEye + ray - uCentres[i]);
      cosv[m] = dot(d, toEye);
      theta[m] = atan(length(cross(d, toEye)), cosv[m]);
      uvs[m] = uv;
      cam[m] = i;
      seen[m] = !visibility || unhidden(i, uv, depth);
      m++;
    }
  }
  if (visibility && m > 1) {  // only the cameras nothing of the view hides the point from, in camera order
    int nv = 0;
    for (int a = 0; a < m; a++) {
      if (!seen[a]) continue;
      cosv[nv] = cosv[a];
      theta[nv] = theta[a];
      uvs[nv] = uvs[a];
      cam[nv] = cam[a];
      nv++;
    }
    if (nv > 0) m = nv;
  }
  if (m == 0) {
    oColour = vec4(uFill / 255.0, 1.0);
    oRegions = vec4(0.0);
    return;
  }
  // the cameras of largest cosine first (a partial selection sort; ties keep camera order)
  int order[N_CAM];
  for (int a = 0; a < N_CAM; a++) order[a] = a;
  int ranked = uMethod == METHOD_KOJIMA ? 2 : (uMethod == METHOD_ULR ? min(uK + 1, N_CAM) : 1);
  int r = min(ranked, m);
  for (int a = 0; a < r; a++) {
    int bi = a;
    for (int b = a + 1; b < m; b++) {
      if (cosv[order[b]] > cosv[order[bi]]) bi = b;
    }
    int t = order[a];
    order[a] = order[bi];
    order[bi] = t;
  }
  int primary = cam[order[0]];
  float w[N_CAM];
  w[0] = 1.0;
  int n = 1;
  if (uMethod == METHOD_KOJIMA && m >= 2) {
    float d12 = cosv[order[0]] - cosv[order[1]];
    float w1 = d12 >= uDBnd ? 1.0 : 0.5 * (1.0 + d12 / uDBnd);
    w[0] = w1;
    w[1] = 1.0 - w1;
    n = 2;
  } else if (uMethod == METHOD_ULR && m >= 2) {
    // the threshold is the angle of the (k+1)-th nearest camera, or of the farthest when there are fewer
    n = m > uK ? uK : m;
    float th = m > uK ? theta[order[uK]] : theta[order[m - 1]];
    float total = 0.0;
    for (int a = 0; a < n; a++) {
      w[a] = th > 0.0 ? max(1.0 - theta[order[a]] / th, 0.0) : 0.0;
      total += w[a];
    }
    for (int a = 0; a < n; a++) w[a] = total > 0.0 ? w[a] / total : 1.0 / float(n);
  } else if (uMethod == METHOD_KOJIMA_K && m >= 2) {
    float cmax = cosv[0];
    for (int a = 1; a < m; a++) cmax = max(cmax, cosv[a]);
    float total = 0.0;
    for (int a = 0; a < m; a++) {
      float d = cmax - cosv[a];
      w[a] = d < uDBnd ? (uDBnd - d) / (uDBnd + d) : 0.0;
      total += w[a];
      order[a] = a;
    }
    for (int a = 0; a < m; a++) w[a] /= total;
    n = m;
  } else if (uMethod == METHOD_GLOBAL) {
    for (int a = 0; a < m; a++) {
      if (cam[a] == uGlobal) order[0] = a;
    }
  }
  vec3 colour = vec3(0.0);
  int regions = 0;
  for (int a = 0; a < n; a++) {
    if (w[a] <= 0.0) continue;
    regions++;
    int o = order[a];
    colour += w[a] * bilinear(cam[o], uvs[o]);
  }
  oColour = vec4(clamp(floor(colour + 0.5), 0.0, 255.0) / 255.0, 1.0);
  oRegions = vec4(float(regions) / 255.0, float(primary + 1) / 255.0, 0.0, 1.0);
}
