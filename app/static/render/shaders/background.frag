#version 300 es
// The live stream's background model (workers/streaming/background.py), one camera (layer) per draw, in colour
// levels / 255 (float). uMode 0: a set flagged as background joins the running mean of consecutive flagged sets
// (weight 1 / run); 1: a normal set updates the model where it shows background (outside the cleaned
// silhouette) by a running average of weight uRate; 2: the model rounded to 8 bits (what silhouettes compare to).
precision highp float;
precision highp int;
precision highp sampler2DArray;
uniform highp sampler2DArray uImages;
uniform highp sampler2DArray uModel;
uniform highp sampler2DArray uMask;
uniform int uLayer;
uniform int uMode;
uniform float uWeight;
out vec4 oModel;

void main() {
  ivec3 p = ivec3(ivec2(gl_FragCoord.xy), uLayer);
  vec4 model = texelFetch(uModel, p, 0);
  vec4 image = vec4(roundEven(texelFetch(uImages, p, 0).rgb * 255.0) / 255.0, 1.0);
  if (uMode == 0) {
    oModel = mix(model, image, uWeight);
  } else if (uMode == 1) {
    oModel = texelFetch(uMask, p, 0).r > 0.5 ? model : mix(model, image, uWeight);
  } else {
    oModel = vec4(clamp(roundEven(model.rgb * 255.0), 0.0, 255.0) / 255.0, 1.0);
  }
}
