// The viewpoint's orbit around the rig (degrees and metres in the hello's orbit frame: workers/streaming/viewpoint.py)
// and the mouse that moves it: drag to turn, wheel to zoom, double-click to go home. Unless freed, the orbit stays
// within the azimuths and elevations the rig's cameras cover (render/rig.js orbitCoverage).
import { clampAzimuth, orbitCoverage } from "./render/rig.js";

export class OrbitInput {
  /** ``free()``: whether the orbit may leave the cameras' coverage; ``changed()``: called after each move. */
  constructor(free, changed) {
    Object.assign(this, { free, changed });
    this.frame = null; // the hello's orbit frame
    this.coverage = null;
    this.azimuth = 0;
    this.elevation = 0;
    this.distance = 1;
    this.outside = false; // the view is outside the coverage (free orbit only)
  }

  /** The hello's orbit ``frame``: its coverage, and the orbit back home. */
  setFrame(frame) {
    this.frame = frame;
    this.coverage = orbitCoverage(frame);
    this.home();
  }

  /** Azimuth 0 at the cameras' mean elevation and distance. */
  home() {
    if (!this.frame) return;
    Object.assign(this, { azimuth: 0, elevation: this.frame.elevation, distance: this.frame.distance, outside: false });
  }

  /** { azimuth, elevation, distance } as a viewpoint's orbit. */
  get pose() {
    return { azimuth: this.azimuth, elevation: this.elevation, distance: this.distance };
  }

  /** Keep the orbit within the cameras' coverage unless it is free; note when it is outside. */
  keepInCoverage() {
    const cov = this.coverage;
    if (!cov) return;
    const az = clampAzimuth(this.azimuth, cov.azimuth);
    const elInside = this.elevation >= cov.elevation[0] && this.elevation <= cov.elevation[1];
    if (this.free()) {
      this.outside = !az.inside || !elInside;
    } else {
      this.azimuth = az.azimuth;
      this.elevation = Math.max(cov.elevation[0], Math.min(cov.elevation[1], this.elevation));
      this.outside = false;
    }
  }

  /** Move the orbit with the mouse over each of ``targets`` (elements). */
  listen(targets) {
    let drag = null;
    const moved = () => {
      this.keepInCoverage();
      this.changed();
    };
    for (const target of targets) {
      target.addEventListener("pointerdown", (event) => {
        drag = { x: event.clientX, y: event.clientY };
        target.setPointerCapture(event.pointerId);
      });
      target.addEventListener("pointermove", (event) => {
        if (!drag) return;
        this.azimuth -= (event.clientX - drag.x) * 0.3;
        this.elevation = Math.max(-85, Math.min(85, this.elevation + (event.clientY - drag.y) * 0.25));
        drag = { x: event.clientX, y: event.clientY };
        moved();
      });
      const endDrag = () => { drag = null; };
      target.addEventListener("pointerup", endDrag);
      target.addEventListener("pointercancel", endDrag);
      target.addEventListener("wheel", (event) => {
        event.preventDefault();
        const home = this.frame ? this.frame.distance : this.distance;
        this.distance = Math.max(0.1 * home, Math.min(10 * home, this.distance * Math.exp(event.deltaY * 0.0015)));
        this.changed();
      }, { passive: false });
      target.addEventListener("dblclick", () => {
        this.home();
        moved();
      });
    }
  }
}
