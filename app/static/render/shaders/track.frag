#version 300 es
// Which camera pixels changed in which frame set (workers/sweep/temporal.py ChangeTracker, _track): per pixel of
// camera uLayer, where a channel of the new frame differs from the reference by more than STILL_LEVELS (0..255; the
// server's, a #define), the reference takes the new value and the change number the set's; else both stay. Slow
// drift below the threshold never adds up to a change of its own making, and a change is seen however many sets it
// took. uFirst: the first set (every pixel new).
precision highp float;
precision highp int;
precision highp sampler2DArray;
uniform highp sampler2DArray uImages;   // RGBA8, the new frame set
uniform highp sampler2DArray uRef;      // RGBA8, each pixel's value at its last change
uniform highp sampler2DArray uChanged;  // R32F, the number of the set of its last change
uniform int uLayer;
uniform float uSet;
uniform bool uFirst;
layout(location = 0) out vec4 oRef;
layout(location = 1) out vec4 oChanged;

void main() {
  ivec3 p = ivec3(ivec2(gl_FragCoord.xy), uLayer);
  vec4 image = texelFetch(uImages, p, 0);
  if (uFirst) {
    oRef = image;
    oChanged = vec4(uSet);
    return;
  }
  vec4 ref = texelFetch(uRef, p, 0);
  vec3 change = abs(roundEven(image.rgb * 255.0) - roundEven(ref.rgb * 255.0));
  bool moved = any(greaterThan(change, vec3(float(STILL_LEVELS))));
  oRef = moved ? image : ref;
  oChanged = moved ? vec4(uSet) : texelFetch(uChanged, p, 0);
}
