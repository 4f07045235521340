// Temporal consistency of the chosen depth (workers/sweep/temporal.py): a view drawn again from the same viewpoint
// on a newer frame set keeps its previous depth wherever the scene did not move, so the picture does not flicker
// where nothing moved. ChangeTracker follows a FrameSet's camera pixels from set to set (track.frag); Hold keeps a
// previous render's resolve output at the pixels whose nearest cameras see them unchanged since (hold.frag).
import { release, target, textureArray } from "./gl.js";
import { Pass } from "./pass.js";
import { viewUniforms } from "./planes.js";

export const SHADERS = ["fullscreen.vert", "rig.glsl", "track.frag", "hold.frag"];

export class ChangeTracker {
  /** For a frame set's ``layers`` camera images of ``width`` x ``height`` (the FrameSet's arrays); ``defines``
   * carries the server's STILL_LEVELS. ``frameSet`` counts the sets seen (0: none yet). */
  constructor(gl, width, height, layers, defines) {
    Object.assign(this, { gl, layers, frameSet: 0 });
    this.ref = [0, 1].map(() => textureArray(gl, "rgba8", width, height, layers));
    this.changed = [0, 1].map(() => textureArray(gl, "r32f", width, height, layers));
    this.pass = new Pass(gl, "track.frag", { defines });
  }

  /** A new frame set is in ``images`` (the FrameSet's array): note the camera pixels it changed. */
  update(images) {
    this.frameSet += 1;
    this.pass.set({ uImages: images, uRef: this.ref[0], uChanged: this.changed[0], uSet: this.frameSet,
      uFirst: this.frameSet === 1 });
    for (let i = 0; i < this.layers; i++) {
      this.pass.set({ uLayer: i });
      this.pass.draw(target(this.gl, [{ tex: this.ref[1], layer: i }, { tex: this.changed[1], layer: i }]));
    }
    this.ref.reverse();
    this.changed.reverse();
  }

  /** The change numbers of the set held now (R32F array: per camera pixel, the set of its last change). */
  get changes() {
    return this.changed[0];
  }

  dispose() {
    release(this.gl, ...this.ref, ...this.changed);
    this.pass.dispose();
  }
}

export class Hold {
  /** The hold pass, compiled with the renderer's ``defines`` (N_CAM, the server's NEAREST_CAMERAS, Z_MIN). */
  constructor(gl, defines) {
    this.gl = gl;
    this.pass = new Pass(gl, "hold.frag", { defines });
  }

  /** Into ``out`` (a 2D rgba32f texture): ``previous`` (the resolve output of a render of the same view, the same
   * planes and depth options, from frame set ``since`` of ``tracker``) where the scene stood still, else ``depth``
   * (the new one). ``sweep``: the new render's ({ geometry, cameras, frames }); ``centres``: the rig's. */
  hold(sweep, virtual, centres, depth, previous, tracker, since, out) {
    this.pass.set({
      ...viewUniforms(sweep, virtual, centres), uDepth: depth, uPrevious: previous, uChanged: tracker.changes,
      uSince: since,
    });
    this.pass.draw(target(this.gl, [out]));
  }

  dispose() {
    this.pass.dispose();
  }
}
