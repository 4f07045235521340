// The rig as the sweep sees it (included by the sweep, search and shade passes).
// Layer i of uImages / uSilhouettes is rig camera i, at the size its calibration has at this source factor.
// For virtual pixel (x, y) (integer pixel centres) and inverse depth s (1/m along the virtual axis), camera i
// sees the point at homogeneous pixel uQ[i] (x, y, 1) + s uB[i] (workers/sweep/kernels.py: the plane-induced
// homography Q + s B e3^T); its depth over the virtual one's is the third coordinate.
uniform highp sampler2DArray uImages;       // RGBA8, colour of each camera's (undistorted) frame
uniform highp sampler2DArray uSilhouettes;  // R8, 1 inside the camera's dilated silhouette
uniform mat3 uQ[N_CAM];
uniform vec3 uB[N_CAM];
uniform vec2 uLast[N_CAM];                  // (W - 1, H - 1) of each camera's image
uniform bool uHull;                         // cull with the silhouettes

// Z_MIN (a point this close to a camera's centre plane, or behind it, gets no vote) and SEARCH_BITS are the server's
// (workers/sweep/layout.py), defined at compile time.
const float BIG = 1e30;       // "no cost": costs are colour levels squared, far below
const float SEARCH_STEP = float(1 << SEARCH_BITS); // the depth search samples at 1/64 px, as the server's kernels do

// The pixel position (u, v) where camera i sees virtual pixel xy at inverse depth s; false behind the camera.
bool projected(int i, vec2 xy, float s, out vec2 uv) {
  vec3 h = uQ[i] * vec3(xy, 1.0) + s * uB[i];
  if (!(h.z > float(Z_MIN))) return false;
  uv = h.xy / h.z;
  return true;
}

// The same, with the point's depth along camera i's axis (its depth over the virtual one's times 1 / s).
bool projectedDepth(int i, vec2 xy, float s, out vec2 uv, out float depth) {
  vec3 h = uQ[i] * vec3(xy, 1.0) + s * uB[i];
  if (!(h.z > float(Z_MIN))) return false;
  uv = h.xy / h.z;
  depth = h.z / s;
  return true;
}

// Whether uv lies inside camera i's image ([0, W-1] x [0, H-1]), the colour pass's test.
bool insideImage(int i, vec2 uv) {
  return all(greaterThanEqual(uv, vec2(0.0))) && all(lessThanEqual(uv, uLast[i]));
}

// Whether camera i's silhouette holds pixel uv (the nearest pixel, ties to even, as the server's lrint).
bool inSilhouette(int i, vec2 uv) {
  ivec2 p = ivec2(roundEven(uv));
  return texelFetch(uSilhouettes, ivec3(p, i), 0).r > 0.5;
}

vec3 texel(int i, ivec2 p) {
  return roundEven(texelFetch(uImages, ivec3(p, i), 0).rgb * 255.0);
}

// Bilinear colour (0..255 per channel) of camera i at uv inside its image ([0, W-1] x [0, H-1]), written as
// nested lerps: a uniform patch gives its value exactly, and at 1/64 px positions the result is exact.
vec3 bilinear(int i, vec2 uv) {
  vec2 f0 = floor(uv);
  ivec2 a = ivec2(f0);
  ivec2 b = min(a + 1, ivec2(uLast[i]));
  vec2 f = uv - f0;
  vec3 top = texel(i, a) + f.x * (texel(i, ivec2(b.x, a.y)) - texel(i, a));
  vec3 bottom = texel(i, ivec2(a.x, b.y)) + f.x * (texel(i, b) - texel(i, ivec2(a.x, b.y)));
  return top + f.y * (bottom - top);
}

// The depth search's sample of camera i at uv: the position rounded to 1/64 px, taken only where that lies
// inside the image (the server's fixed-point test). Returns false where the camera does not vote.
bool searchSample(int i, vec2 uv, out vec3 colour) {
  vec2 q = roundEven(uv * SEARCH_STEP);
  vec2 last = uLast[i] * SEARCH_STEP;
  if (any(lessThan(q, vec2(0.0))) || any(greaterThan(q, last))) return false;
  colour = bilinear(i, q / SEARCH_STEP);
  return true;
}

// The photo-consistency sums of virtual pixel xy at inverse depth s: x = the squared deviations of the voting
// cameras' samples from their mean, summed over the channels (colour levels squared), y = the votes; (0, 0)
// where fewer than minViews cameras vote or, with the hull, a camera sees the point outside its silhouette.
// Welford's running mean keeps float32 exact where every sample is equal (zero variance stays zero).
vec2 consistency(vec2 xy, float s, int minViews) {
  vec3 mean = vec3(0.0);
  vec3 m2 = vec3(0.0);
  float n = 0.0;
  for (int i = 0; i < N_CAM; i++) {
    vec2 uv;
    if (!projected(i, xy, s, uv)) continue;
    vec3 c;
    if (!searchSample(i, uv, c)) continue;
    if (uHull && !inSilhouette(i, uv)) return vec2(0.0);
    n += 1.0;
    vec3 d = c - mean;
    mean += d / n;
    m2 += d * (c - mean);
  }
  if (n < float(minViews)) return vec2(0.0);
  return vec2(m2.r + m2.g + m2.b, n);
}
