#version 300 es
// Silhouettes by background subtraction (workers/sweep/silhouette.py), one camera (layer) per draw:
// pass "foreground": 1 where the largest channel difference from the empty-scene image exceeds the
// threshold; passes "erode" / "dilate": a morphological step with a kernel given as offsets (the cleaning
// disk's opening and closing, then the hull's square dilation). Pixels beyond the border never erode a
// pixel and never dilate one (OpenCV's default border for morphology).
precision highp float;
precision highp int;
precision highp sampler2DArray;
uniform highp sampler2DArray uImages;
uniform highp sampler2DArray uBackgrounds;
uniform highp sampler2DArray uMask;
uniform int uLayer;
uniform ivec2 uSize;        // this camera's image size (the array may be larger)
uniform int uMode;          // 0 foreground, 1 erode, 2 dilate
uniform float uThreshold;   // largest channel difference (0..255) of the background
uniform int uTaps;
uniform ivec2 uKernel[MAX_TAPS];
out vec4 oMask;

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  if (p.x >= uSize.x || p.y >= uSize.y) {
    oMask = vec4(0.0);
    return;
  }
  if (uMode == 0) {
    vec3 a = roundEven(texelFetch(uImages, ivec3(p, uLayer), 0).rgb * 255.0);
    vec3 b = roundEven(texelFetch(uBackgrounds, ivec3(p, uLayer), 0).rgb * 255.0);
    vec3 d = abs(a - b);
    oMask = vec4(max(max(d.r, d.g), d.b) > uThreshold ? 1.0 : 0.0);
    return;
  }
  bool erode = uMode == 1;
  bool result = erode;
  for (int t = 0; t < uTaps; t++) {
    ivec2 q = p + uKernel[t];
    if (q.x < 0 || q.y < 0 || q.x >= uSize.x || q.y >= uSize.y) continue;
    bool on = texelFetch(uMask, ivec3(q, uLayer), 0).r > 0.5;
    if (erode && !on) result = false;
    if (!erode && on) result = true;
  }
  oMask = vec4(result ? 1.0 : 0.0);
}
