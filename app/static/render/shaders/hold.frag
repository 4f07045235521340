#version 300 es
// A view drawn again on a newer frame set keeps its previous depth where the scene did not move
// (workers/sweep/temporal.py still_pixels, _still; workers/sweep/renderer.py render's ``previous``): at a pixel
// whose previous surface point the NEAREST_CAMERAS cameras nearest to the view by angle (of those that see it in
// front of them and inside their image: the ones its colour comes from) sample from pixels unchanged since the
// previous render's frame set (uSince), the previous resolve output is kept whole (depth, plane, offset, cost and
// the fill's mark); elsewhere the new one. NEAREST_CAMERAS is the server's (a #define).
precision highp float;
precision highp int;
precision highp sampler2DArray;
#include "rig.glsl"
uniform highp sampler2D uDepth;         // the new resolve output: .x inverse depth (0: no surface)
uniform highp sampler2D uPrevious;      // the previous render's
uniform highp sampler2DArray uChanged;  // per camera: the set number of each pixel's last change (track.frag)
uniform float uSince;
uniform mat3 uG;                        // virtual ray of pixel (x, y) at unit depth
uniform vec3 uEye;                      // virtual camera centre
uniform vec3 uCentres[N_CAM];           // rig camera centres
out vec4 oDepth;

// The latest change among the four pixels camera i samples the colour at uv from (as bilinear() does).
float latestChange(int i, vec2 uv) {
  ivec2 a = ivec2(floor(uv));
  ivec2 b = min(a + 1, ivec2(uLast[i]));
  return max(max(texelFetch(uChanged, ivec3(a, i), 0).x, texelFetch(uChanged, ivec3(b.x, a.y, i), 0).x),
             max(texelFetch(uChanged, ivec3(a.x, b.y, i), 0).x, texelFetch(uChanged, ivec3(b, i), 0).x));
}

bool still(vec2 xy, float s) {
  vec3 ray = uG * vec3(xy, 1.0) / s;  // from the virtual centre to the previous surface point
  float cosv[N_CAM];
  float latest[N_CAM];
  int m = 0;
  for (int i = 0; i < N_CAM; i++) {
    vec2 uv;
    if (!projected(i, xy, s, uv) || !insideImage(i, uv)) continue;
    vec3 d = uEye + ray - uCentres[i];
    cosv[m] = dot(d, ray) / length(d);
    latest[m] = latestChange(i, uv);
    m++;
  }
  if (m == 0) return false;
  for (int k = 0; k < min(NEAREST_CAMERAS, m); k++) {  // the largest cosines first (a partial selection)
    int b = 0;
    for (int a = 1; a < m; a++) {
      if (cosv[a] > cosv[b]) b = a;
    }
    if (latest[b] > uSince) return false;
    cosv[b] = -BIG;
  }
  return true;
}

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec4 previous = texelFetch(uPrevious, p, 0);
  float s = previous.x;
  oDepth = s > 0.0 && still(gl_FragCoord.xy - 0.5, s) ? previous : texelFetch(uDepth, p, 0);
}
