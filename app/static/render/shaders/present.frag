#version 300 es
// The picture shown: the view, the view tinted by its region map (workers/sweep/overlays.py regions_image:
// a colour per camera where one camera colours it, black where two blend, red where three or more do), or
// the depth map (inverse depth through the server's colour map, black without a surface).
// uFlip: write row 0 of the view at the top of a canvas (the default framebuffer counts rows from the bottom).
precision highp float;
precision highp int;
uniform highp sampler2D uColour;
uniform highp sampler2D uRegions;
uniform highp sampler2D uDepth;
uniform highp sampler2D uColourMap;  // 256 x 1 RGBA8: the depth colour map
uniform vec3 uPalette[PALETTE];      // RGB 0..255, one-camera region colours by camera (cycled)
uniform vec3 uBlend2;
uniform vec3 uBlend3;
uniform float uOverlayWeight;
uniform int uOverlay;                // the server's code of the overlay (OVERLAY_NONE, _REGIONS, _DEPTH)
uniform vec2 uInverseRange;          // min, max inverse depth found in the view
uniform bool uFlip;
out vec4 oColour;

void main() {
  ivec2 size = textureSize(uColour, 0);
  ivec2 p = ivec2(gl_FragCoord.xy);
  if (uFlip) p.y = size.y - 1 - p.y;
  vec4 colour = texelFetch(uColour, p, 0);
  if (uOverlay == OVERLAY_REGIONS) {
    vec2 r = roundEven(texelFetch(uRegions, p, 0).rg * 255.0);
    if (r.x > 0.0) {
      vec3 tint = r.x >= 3.0 ? uBlend3 : (r.x == 2.0 ? uBlend2 : uPalette[(int(r.y) - 1) % PALETTE]);
      colour.rgb = roundEven(roundEven(colour.rgb * 255.0) * (1.0 - uOverlayWeight) + tint * uOverlayWeight) / 255.0;
    }
  } else if (uOverlay == OVERLAY_DEPTH) {
    float s = texelFetch(uDepth, p, 0).x;
    if (s > 0.0) {
      float span = uInverseRange.y > uInverseRange.x ? uInverseRange.y - uInverseRange.x : 1.0;
      int level = int(clamp(roundEven(255.0 * (s - uInverseRange.x) / span), 0.0, 255.0));
      colour = vec4(texelFetch(uColourMap, ivec2(level, 0), 0).rgb, 1.0);
    } else {
      colour = vec4(0.0, 0.0, 0.0, 1.0);
    }
  }
  oColour = vec4(colour.rgb, 1.0);
}
