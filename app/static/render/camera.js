// Pinhole cameras as the server has them (workers/camera.py): K (3x3), world-to-camera R (3x3) and t (3),
// x_cam = R X + t, OpenCV axes, pixel (0, 0) at the centre of the top-left pixel. Matrices are row-major
// arrays of 9 numbers, vectors arrays of 3; everything in float64 (JavaScript numbers).

export const mat3 = {
  mul(a, b) {
    const o = new Array(9);
    for (let r = 0; r < 3; r++) {
      for (let c = 0; c < 3; c++) o[3 * r + c] = a[3 * r] * b[c] + a[3 * r + 1] * b[3 + c] + a[3 * r + 2] * b[6 + c];
    }
    return o;
  },
  vec(a, v) {
    return [0, 1, 2].map((r) => a[3 * r] * v[0] + a[3 * r + 1] * v[1] + a[3 * r + 2] * v[2]);
  },
  transpose(a) {
    return [a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8]];
  },
  inverse(a) {
    const [a0, a1, a2, a3, a4, a5, a6, a7, a8] = a;
    const c0 = a4 * a8 - a5 * a7;
    const c1 = a5 * a6 - a3 * a8;
    const c2 = a3 * a7 - a4 * a6;
    const det = a0 * c0 + a1 * c1 + a2 * c2;
    if (!(Math.abs(det) > 0)) throw new Error("singular 3x3 matrix");
    const d = 1 / det;
    return [c0 * d, (a2 * a7 - a1 * a8) * d, (a1 * a5 - a2 * a4) * d,
      c1 * d, (a0 * a8 - a2 * a6) * d, (a2 * a3 - a0 * a5) * d,
      c2 * d, (a1 * a6 - a0 * a7) * d, (a0 * a4 - a1 * a3) * d];
  },
};

export const vec3 = {
  add: (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]],
  sub: (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]],
  scale: (a, s) => [a[0] * s, a[1] * s, a[2] * s],
  dot: (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2],
  cross: (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]],
  norm: (a) => Math.hypot(a[0], a[1], a[2]),
  unit: (a) => vec3.scale(a, 1 / vec3.norm(a)),
};

/** Python's round(): halves to even (sizes must round as the server's do: Camera.scaled). */
function roundHalfEven(x) {
  const r = Math.round(x);
  return Math.abs(x % 1) === 0.5 && r % 2 !== 0 ? r - 1 : r;
}

export class Camera {
  /** name; K, R row-major arrays of 9; t array of 3; width, height in pixels. */
  constructor(name, K, R, t, width, height) {
    Object.assign(this, { name, K: [...K], R: [...R], t: [...t], width, height });
  }

  /** Centre in world coordinates: -R^T t. */
  get center() {
    return vec3.scale(mat3.vec(mat3.transpose(this.R), this.t), -1);
  }

  /** Unit optical axis (camera +z) in world coordinates. */
  get axis() {
    return this.R.slice(6, 9);
  }

  /** World point (3) -> camera-frame point (3). */
  toCamera(X) {
    return vec3.add(mat3.vec(this.R, X), this.t);
  }

  /** World point of pixel (u, v) at ``depth`` metres along the axis. */
  backproject(u, v, depth) {
    const ray = mat3.vec(mat3.inverse(this.K), [u, v, 1]);
    return mat3.vec(mat3.transpose(this.R), vec3.sub(vec3.scale(ray, depth), this.t));
  }

  /** The camera of the image resized by ``factor`` (pixel-centre convention kept; Camera.scaled). */
  scaled(factor) {
    const K = [...this.K];
    K[0] *= factor; K[1] *= factor; K[3] *= factor; K[4] *= factor;
    K[2] = (this.K[2] + 0.5) * factor - 0.5;
    K[5] = (this.K[5] + 0.5) * factor - 0.5;
    const w = Math.max(1, roundHalfEven(this.width * factor));
    const h = Math.max(1, roundHalfEven(this.height * factor));
    return new Camera(this.name, K, this.R, this.t, w, h);
  }

  /** A camera at ``eye`` looking at ``target`` with world ``up`` shown upwards, horizontal field of view
   * ``fovDeg``, square pixels, principal point at the image centre (Camera.look_at). */
  static lookAt(name, eye, target, up, fovDeg, width, height) {
    let z = vec3.sub(target, eye);
    if (!(vec3.norm(z) > 0)) throw new Error("the target equals the eye position");
    z = vec3.unit(z);
    let x = vec3.cross(z, up);
    if (vec3.norm(x) < 1e-9) throw new Error("up is parallel to the viewing direction");
    x = vec3.unit(x);
    const y = vec3.cross(z, x);
    const f = 0.5 * width / Math.tan((fovDeg * Math.PI) / 360);
    const K = [f, 0, (width - 1) / 2, 0, f, (height - 1) / 2, 0, 0, 1];
    const R = [...x, ...y, ...z];
    return new Camera(name, K, R, vec3.scale(mat3.vec(R, eye), -1), width, height);
  }
}
