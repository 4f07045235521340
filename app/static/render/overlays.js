// The picture shown: the view, the view under its region map, or the depth map
// (workers/streaming/session.py _composed, workers/sweep/overlays.py). Colours come from the server's hello.
import { release } from "./gl.js";
import { Pass } from "./pass.js";

export const SHADERS = ["fullscreen.vert", "present.frag"];

/** The depth colour map (256 RGB triples) as a 256 x 1 RGBA8 texture. */
function colourMapTexture(gl, rgb) {
  const data = new Uint8Array(256 * 4);
  rgb.forEach(([r, g, b], i) => data.set([r, g, b, 255], 4 * i));
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, t);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA8, 256, 1, 0, gl.RGBA, gl.UNSIGNED_BYTE, data);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
  return { texture: t, width: 256, height: 1 };
}

export class Presenter {
  /** The present pass for the hello's ``style`` (palette, blend2, blend3, weight: RGB and the overlay's weight;
   * colour_map: 256 RGB triples), compiled with the renderer's ``defines`` (PALETTE, OVERLAY_* codes). */
  constructor(gl, style, defines) {
    this.gl = gl;
    this.colourMap = colourMapTexture(gl, style.colour_map);
    this.pass = new Pass(gl, "present.frag", { defines });
    this.pass.set({ uPalette: style.palette, uBlend2: style.blend2, uBlend3: style.blend3,
      uOverlayWeight: style.weight, uColourMap: this.colourMap });
  }

  /** Compose ``overlay`` (its code: the render block's rules.codes.overlay) of ``work`` (its colour, regions and
   * depth) with the depth map's ``inverseRange`` into ``into`` (a target; the canvas: flipped to show row 0 on top). */
  present(work, overlay, inverseRange, into) {
    this.pass.set({ uColour: work.colour, uRegions: work.regions, uDepth: work.depth, uOverlay: overlay,
      uInverseRange: inverseRange, uFlip: into.fb === null });
    this.pass.draw(into);
  }

  dispose() {
    release(this.gl, this.colourMap);
    this.pass.dispose();
  }
}
