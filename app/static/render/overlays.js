// The picture shown: the view, the view under its region map, or the depth map
// (workers/streaming/session.py _composed, workers/sweep/overlays.py). Colours come from the server's hello.
import { bindTextures, drawFullscreen } from "./gl.js";

export const SHADERS = ["fullscreen.vert", "present.frag"];

/** The depth colour map (256 RGB triples) as a 256 x 1 RGBA8 texture. */
export function colourMapTexture(gl, rgb) {
  const data = new Uint8Array(256 * 4);
  rgb.forEach(([r, g, b], i) => data.set([r, g, b, 255], 4 * i));
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, t);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA8, 256, 1, 0, gl.RGBA, gl.UNSIGNED_BYTE, data);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
  return { texture: t, width: 256, height: 1 };
}

/** Compose ``overlay`` (its code: the render block's rules.codes.overlay) into ``target`` (a framebuffer record;
 * null: the canvas, flipped to show row 0 on top). */
export function present(gl, prog, work, style, overlay, inverseRange, target) {
  gl.useProgram(prog.program);
  bindTextures(gl, prog, { uColour: work.colour, uRegions: work.regions, uDepth: work.depth, uColourMap: style.colourMap });
  const u = prog.uniforms;
  gl.uniform3fv(u["uPalette[0]"], Float32Array.from(style.palette.flat()));
  gl.uniform3fv(u.uBlend2, Float32Array.from(style.blend2));
  gl.uniform3fv(u.uBlend3, Float32Array.from(style.blend3));
  gl.uniform1f(u.uOverlayWeight, style.weight);
  gl.uniform1i(u.uOverlay, overlay);
  gl.uniform2f(u.uInverseRange, inverseRange[0], inverseRange[1]);
  gl.uniform1i(u.uFlip, target ? 0 : 1);
  drawFullscreen(gl, target, work.width, work.height);
}
