// The rig as the browser renderer needs it: its cameras (at a source factor), the working volume that sets the
// automatic depth range, the camera spacing that sets the automatic D_bnd, and orbits around it. Mirrors
// workers/sweep/rig.py, workers/sweep/weighting.py and workers/streaming/viewpoint.py; the server sends what
// depends on the rig alone (the cameras at every source factor, focus point, radius) and the constants of its
// rules in the hello's render block, and the orbit frame in the hello itself, so only per-view geometry is
// computed here.
import { Camera, vec3 } from "./camera.js";

export class Rig {
  /**
   * spec: the hello's ``render`` block: { poses: [{R, t}] (rig order), sources: [{factor, views_up_to: [w, h],
   * cameras: [{K, width, height}]}] (workers/streaming/browser.py frame_sources), focus: [3], radius,
   * depth_range: [near, far] | null, rules: { constants } } (calibration undistorted: frames come undistorted).
   */
  constructor(spec) {
    this.poses = spec.poses;
    this.sources = spec.sources;
    this.focus = spec.focus;
    this.radius = spec.radius;
    this.depthRange = spec.depth_range || null;
    this.constants = spec.rules.constants;
    const cameras = this.camerasAt(1);
    this.centres = cameras.map((c) => c.center);
    this.axes = cameras.map((c) => c.axis);
  }

  get size() {
    return this.poses.length;
  }

  /** The source a view of width x height px sweeps: { factor, cameras } of the largest factor whose frames serve
   * it, else factor 1's (the server's table: session.source_factor). */
  sourceFor(width, height) {
    const fits = (s) => width <= s.views_up_to[0] && height <= s.views_up_to[1];
    return this.sources.findLast((s) => s.factor > 1 && fits(s)) ?? this.sources[0];
  }

  /** The cameras (Camera, rig order) of frames shrunk by ``factor``, as the server sent them. */
  camerasAt(factor) {
    const source = this.sources.find((s) => s.factor === factor);
    if (!source) throw new Error(`the server sent no cameras for source factor ${factor}`);
    return source.cameras.map((c, i) => new Camera(String(i), c.K.flat(), this.poses[i].R.flat(), this.poses[i].t,
      c.width, c.height));
  }

  /** (near, far) metres along ``virtual``'s axis: the rig's depth range, else its working volume's
   * (Rig.auto_depth_range: far = z_c + R, near = max(z_c - R/2, far / NEAR_FAR_RATIO)). */
  autoDepthRange(virtual) {
    if (this.depthRange) return this.depthRange;
    const z = virtual.toCamera(this.focus)[2];
    const far = z + this.radius;
    if (!(far > 0)) throw new Error("the rig's working volume is behind the virtual camera; give near/far");
    return [Math.max(z - 0.5 * this.radius, far / this.constants.near_far_ratio), far];
  }

  /** Median over cameras of the angle (rad) to the nearest other camera seen from ``point`` (neighbour_angle);
   * cameras at one place (< 1e-6 rad) are not each other's neighbours; 0 when none has a neighbour. */
  neighbourAngle(point) {
    const dirs = this.centres.map((c) => vec3.unit(vec3.sub(c, point)));
    const nearest = [];
    dirs.forEach((a, i) => {
      let best = Infinity;
      dirs.forEach((b, j) => {
        if (i === j) return;
        const angle = Math.acos(Math.min(1, Math.max(-1, vec3.dot(a, b))));
        if (angle >= 1e-6) best = Math.min(best, angle);
      });
      if (Number.isFinite(best)) nearest.push(best);
    });
    return nearest.length ? median(nearest) : 0;
  }

  /** D_bnd blending over a share (AUTO_BLEND_FRACTION) of the angle between neighbouring cameras, seen from the
   * point on ``virtual``'s central ray at depth ``medianDepth`` (SweepRenderer.auto_d_bnd; suggest_d_bnd). */
  autoDBnd(virtual, medianDepth) {
    const z = Number.isFinite(medianDepth) && medianDepth > 0 ? medianDepth : 1.0;
    const point = virtual.backproject((virtual.width - 1) / 2, (virtual.height - 1) / 2, z);
    const spacing = this.neighbourAngle(point);
    const angle = spacing > 0 ? spacing : this.constants.fallback_spacing_rad;
    return (this.constants.auto_blend_fraction * angle * angle) / 2;
  }

  /** The camera whose optical axis is closest to ``virtual``'s (the global method's one camera). */
  globalCamera(virtual) {
    const axis = virtual.axis;
    let best = 0;
    this.axes.forEach((a, i) => {
      if (vec3.dot(a, axis) > vec3.dot(this.axes[best], axis)) best = i;
    });
    return best;
  }
}

/** The virtual camera of ``orbit`` {azimuth, elevation?, distance?, target?} (degrees, metres) in orbit frame
 * ``frame`` (the hello's ``orbit``: viewpoint.OrbitFrame) at width x height with horizontal field of view ``fov``
 * (viewpoint.orbit_camera). */
export function orbitCamera(frame, orbit, fov, width, height) {
  const f = frame;
  const elevation = Math.min(89, Math.max(-89, orbit.elevation ?? f.elevation));
  const distance = orbit.distance ?? f.distance;
  const target = orbit.target ?? f.target;
  const a = (orbit.azimuth * Math.PI) / 180;
  const e = (elevation * Math.PI) / 180;
  const side = f.side ?? vec3.cross(f.up, f.forward);
  const horizontal = vec3.add(vec3.scale(f.forward, Math.cos(a)), vec3.scale(side, Math.sin(a)));
  const eye = vec3.add(target, vec3.scale(vec3.add(vec3.scale(horizontal, Math.cos(e)), vec3.scale(f.up, Math.sin(e))), distance));
  return Camera.lookAt("virtual", eye, target, f.up, fov, width, height);
}

/** The median of a list of numbers (the mean of the two middle ones for an even count, as numpy's). */
export function median(values) {
  const a = Float64Array.from(values).sort();
  const n = a.length;
  if (!n) return NaN;
  return n % 2 ? a[(n - 1) / 2] : 0.5 * (a[n / 2 - 1] + a[n / 2]);
}

/**
 * The orbit range the rig's cameras cover (degrees): { azimuth: [lo, hi] | null (cameras all around),
 * elevation: [lo, hi] }, each side widened by ``margin`` (default: half the median azimuth spacing of
 * neighbouring cameras, at least 5 degrees). orbit: the hello's orbit frame (camera_azimuths, camera_elevations).
 */
export function orbitCoverage(orbit, margin = null) {
  const az = [...orbit.camera_azimuths].sort((a, b) => a - b);
  const n = az.length;
  const gaps = az.map((a, i) => (i + 1 < n ? az[i + 1] - a : az[0] + 360 - a));
  const widest = gaps.indexOf(Math.max(...gaps));
  const spacing = median(gaps.filter((_, i) => i !== widest));
  const m = margin ?? Math.max(5, 0.5 * (Number.isFinite(spacing) ? spacing : 10));
  const el = orbit.camera_elevations;
  const elevation = [Math.max(-89, Math.min(...el) - 3 * m), Math.min(89, Math.max(...el) + 3 * m)];
  if (gaps[widest] <= 2 * m + 1e-9) return { azimuth: null, elevation, margin: m };
  const lo = az[(widest + 1) % n];
  const hi = widest + 1 < n ? az[widest] + 360 : az[widest];
  return { azimuth: [lo - m, hi + m], elevation, margin: m };
}

/** ``azimuth`` (degrees, any turn) kept within ``range`` ([lo, hi] in some turn; null: any azimuth): returns
 * { azimuth, inside }, the azimuth moved to the range's nearer end (in the caller's turn) when it was outside. */
export function clampAzimuth(azimuth, range) {
  if (!range) return { azimuth, inside: true };
  const centre = 0.5 * (range[0] + range[1]);
  const half = 0.5 * (range[1] - range[0]);
  const d = ((((azimuth - centre) % 360) + 540) % 360) - 180; // [-180, 180) from the centre
  const inside = Math.abs(d) <= half;
  return { azimuth: inside ? azimuth : azimuth + (Math.max(-half, Math.min(half, d)) - d), inside };
}
