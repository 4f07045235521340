// A frame set on the GPU: every camera's frame as one layer of an RGBA8 array texture, the empty-scene images
// likewise, and the silhouettes made from them (workers/sweep/silhouette.py): foreground where the largest
// channel difference exceeds the threshold, cleaned by an opening and a closing with the server's disk, then
// dilated by the hull margin (a square). Frame sets arrive as one image, an atlas of the cameras' frames in
// rig order, ``columns`` cells per row, each cell the size of the largest camera image. Every set is followed by its
// ChangeTracker (temporal.js: which camera pixels changed in which set).
import { release, target, textureArray } from "./gl.js";
import { Pass } from "./pass.js";
import { ChangeTracker, SHADERS as TEMPORAL_SHADERS } from "./temporal.js";

export const SHADERS = ["fullscreen.vert", "silhouette.frag", "background.frag", ...TEMPORAL_SHADERS];

/** The cell (column, row) of camera ``i`` in an atlas of ``columns`` cells per row. */
export function atlasCell(i, columns) {
  return [i % columns, Math.floor(i / columns)];
}

export class FrameSet {
  /** sizes: [[w, h]] per camera (at the source factor); silhouettes: {threshold, clean: [[dx, dy]], dilate};
   * defines: the renderer's (the server's STILL_LEVELS for the change tracker). */
  constructor(gl, sizes, silhouettes, defines) {
    this.gl = gl;
    this.sizes = sizes;
    this.width = Math.max(...sizes.map((s) => s[0]));
    this.height = Math.max(...sizes.map((s) => s[1]));
    this.layers = sizes.length;
    this.params = silhouettes;
    this.images = textureArray(gl, "rgba8", this.width, this.height, this.layers);
    this.backgrounds = null;
    this.silhouettes = textureArray(gl, "r8", this.width, this.height, this.layers);
    this.scratch = textureArray(gl, "r8", this.width, this.height, this.layers);
    this.hasSilhouettes = false;
    this.maxTaps = Math.max(this.params.clean.length, (2 * this.params.dilate + 1) ** 2, 1);
    this.silhouettePass = new Pass(gl, "silhouette.frag", { defines: { MAX_TAPS: this.maxTaps } });
    this.modelPass = new Pass(gl, "background.frag");
    this.model = null; // live: the float background model, two arrays (ping-pong)
    this.flaggedRun = 0;
    this.changes = new ChangeTracker(gl, this.width, this.height, this.layers, defines);
    this.fill(this.silhouettes, 1);
  }

  /** Upload an atlas (ImageBitmap, canvas or image) of the frames; ``columns`` cells per row. */
  setFrames(atlas, columns) {
    this.upload(this.images, atlas, columns);
    this.changes.update(this.images);
    if (this.backgrounds) this.makeSilhouettes();
  }

  /** Upload an atlas of the empty-scene images (then every frame set gets silhouettes). */
  setBackgrounds(atlas, columns) {
    if (!this.backgrounds) this.backgrounds = textureArray(this.gl, "rgba8", this.width, this.height, this.layers);
    this.upload(this.backgrounds, atlas, columns);
  }

  /** Upload one camera's frame (an ImageBitmap of its size) into layer ``i`` (the live stream's path). */
  setCamera(i, bitmap, target = this.images) {
    const gl = this.gl;
    gl.bindTexture(gl.TEXTURE_2D_ARRAY, target.texture);
    unpackDefaults(gl);
    gl.texSubImage3D(gl.TEXTURE_2D_ARRAY, 0, 0, 0, i, bitmap.width, bitmap.height, 1, gl.RGBA, gl.UNSIGNED_BYTE, bitmap);
  }

  upload(target, atlas, columns) {
    const gl = this.gl;
    gl.bindTexture(gl.TEXTURE_2D_ARRAY, target.texture);
    unpackDefaults(gl);
    gl.pixelStorei(gl.UNPACK_ROW_LENGTH, atlas.width);
    this.sizes.forEach(([w, h], i) => {
      const [col, row] = atlasCell(i, columns);
      gl.pixelStorei(gl.UNPACK_SKIP_PIXELS, col * this.width);
      gl.pixelStorei(gl.UNPACK_SKIP_ROWS, row * this.height);
      gl.texSubImage3D(gl.TEXTURE_2D_ARRAY, 0, 0, 0, i, w, h, 1, gl.RGBA, gl.UNSIGNED_BYTE, atlas);
    });
    unpackDefaults(gl);
  }

  /** Silhouettes of the current frames against the backgrounds (six passes per camera). ``cleaned`` (optional)
   * is called with the mask array holding the cleaned silhouettes before the hull's dilation. */
  makeSilhouettes(cleaned = null) {
    const { threshold, clean, dilate } = this.params;
    const square = [];
    for (let dy = -dilate; dy <= dilate; dy++) for (let dx = -dilate; dx <= dilate; dx++) square.push([dx, dy]);
    const steps = [[0, []]];
    if (clean.length) steps.push([1, clean], [2, clean], [2, clean], [1, clean]); // opening, then closing
    const cleanSteps = steps.length;
    if (dilate > 0) steps.push([2, square]);
    // ping-pong between the two mask arrays so that the last step writes the silhouettes
    let dst = steps.length % 2 === 1 ? this.silhouettes : this.scratch;
    let src = dst === this.silhouettes ? this.scratch : this.silhouettes;
    steps.forEach(([mode, kernel], k) => {
      this.morph(mode, kernel, src, dst);
      if (k === cleanSteps - 1 && cleaned) cleaned(dst);
      [src, dst] = [dst, src];
    });
    this.hasSilhouettes = true;
  }

  /** Start the live background model from an atlas of the server's model (PNG, the frames' layout). */
  setLiveModel(atlas, columns) {
    this.setBackgrounds(atlas, columns);
    const gl = this.gl;
    if (!this.model) this.model = [0, 1].map(() => textureArray(gl, "rgba32f", this.width, this.height, this.layers));
    this.modelStep(2, this.backgrounds, this.model[0], 0, this.backgrounds); // a float copy of the 8-bit model
    this.flaggedRun = 0;
  }

  /** A live frame set was uploaded (setCamera per camera): follow the server's BackgroundModel.observe. A set
   * flagged as background joins the model and shows nothing (all silhouettes empty); a normal one gets
   * silhouettes against the model (none while there is no model), then updates the model outside them. */
  observeLive(isBackground, rate) {
    const gl = this.gl;
    this.changes.update(this.images); // every set, a background one too (the server's set_frames)
    if (isBackground) {
      this.flaggedRun += 1;
      if (!this.model) {
        this.model = [0, 1].map(() => textureArray(gl, "rgba32f", this.width, this.height, this.layers));
        this.backgrounds = this.backgrounds || textureArray(gl, "rgba8", this.width, this.height, this.layers);
      }
      this.modelStep(0, this.model[0], this.model[1], this.flaggedRun === 1 ? 1 : 1 / this.flaggedRun, this.scratch);
      this.model.reverse();
      this.modelStep(2, this.model[0], this.backgrounds, 0, this.scratch);
      this.fill(this.silhouettes, 0);
      this.hasSilhouettes = true;
      return;
    }
    this.flaggedRun = 0;
    if (!this.model) {
      this.fill(this.silhouettes, 1);
      this.hasSilhouettes = false;
      return;
    }
    this.makeSilhouettes((mask) => {
      this.modelStep(1, this.model[0], this.model[1], rate, mask);
      this.model.reverse();
    });
    this.modelStep(2, this.model[0], this.backgrounds, 0, this.scratch);
  }

  /** One step of the live background model (background.frag, ``mode``) from ``src`` into ``dst``, a camera a draw. */
  modelStep(mode, src, dst, weight, mask) {
    this.modelPass.set({ uImages: this.images, uModel: src, uMask: mask, uMode: mode, uWeight: weight });
    for (let i = 0; i < this.layers; i++) {
      this.modelPass.set({ uLayer: i });
      this.modelPass.draw(target(this.gl, [{ tex: dst, layer: i }]));
    }
  }

  /** One silhouette step (silhouette.frag, ``mode``) with ``kernel`` (offsets) from mask ``src`` into ``dst``. */
  morph(mode, kernel, src, dst) {
    this.silhouettePass.set({ uImages: this.images, uBackgrounds: this.backgrounds, uMask: src, uMode: mode,
      uThreshold: this.params.threshold, uTaps: kernel.length });
    this.silhouettePass.set({ uKernel: kernel.length ? kernel : [[0, 0]] }); // no taps: the foreground reads none
    this.sizes.forEach(([w, h], i) => {
      this.silhouettePass.set({ uLayer: i, uSize: [w, h] });
      this.silhouettePass.draw(target(this.gl, [{ tex: dst, layer: i }]));
    });
  }

  /** Set every layer of a mask array to ``value`` (1: no hull culling anywhere). */
  fill(tex, value) {
    const gl = this.gl;
    for (let i = 0; i < this.layers; i++) {
      gl.bindFramebuffer(gl.FRAMEBUFFER, target(gl, [{ tex, layer: i }]).fb);
      gl.clearBufferfv(gl.COLOR, 0, [value, value, value, value]);
    }
  }

  dispose() {
    release(this.gl, this.images, this.backgrounds, this.silhouettes, this.scratch, ...(this.model || []));
    this.changes.dispose();
    this.silhouettePass.dispose();
    this.modelPass.dispose();
  }
}

function unpackDefaults(gl) {
  gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, false);
  gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, false);
  gl.pixelStorei(gl.UNPACK_COLORSPACE_CONVERSION_WEBGL, gl.NONE);
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
  gl.pixelStorei(gl.UNPACK_ROW_LENGTH, 0);
  gl.pixelStorei(gl.UNPACK_SKIP_PIXELS, 0);
  gl.pixelStorei(gl.UNPACK_SKIP_ROWS, 0);
}
