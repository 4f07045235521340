// What the page measures of the views it shows (read by the browser tests and the benchmarks too) and the panel that
// says it: state, who renders, the quality level, fps, latency, render time, pose, depth, a live set's spread; the
// notices and errors above the view.

const $ = (id) => document.getElementById(id);
const LEVEL_TEXT = { best: "best: semi-global depth, occlusions filled", fast: "fast: semi-global depth" };

export class Stats {
  constructor() {
    this.received = 0; // views shown
    this.arrivals = []; // performance.now() of each view shown in the last 2 s
    this.latencies = []; // ms from a user's change (or a viewpoint's send) to its view on screen, the last 50
    this.captureLatencies = []; // live: ms from each shown set's capture time to its view here, the last 200
    this.errors = []; // the socket's errors and the browser renderer's
    this.firstFrameAt = null; // performance.now() when the first view was drawn (ms since the page's navigation)
    this.changedAt = null; // when the user changed the view, until a view asks for it
  }

  /** The user changed the view (its latency counts from the first change not yet asked for). */
  changed() {
    if (this.changedAt === null) this.changedAt = performance.now();
  }

  /** When the user changed the view (null: not since the last ask), now asked for. */
  takeChange() {
    const at = this.changedAt;
    this.changedAt = null;
    return at;
  }

  /** A view is on screen; ``since``: when it was asked for (null: not a user's change); ``at``: when it arrived
   * (a frame from the server: before it was decoded). */
  shown(since = null, at = performance.now()) {
    if (since !== null) this.latencies.push(at - since);
    this.firstFrameAt ??= performance.now();
    this.received += 1;
    this.arrivals.push(at);
  }

  /** Capture-to-frame: from a live set's capture time (its instant, s since the epoch, on the cameras' clock) to the
   * view on this screen now (meaningful where this machine's clock and the cameras' agree). */
  captured(at) {
    if (at === null || at === undefined) return;
    this.captureLatencies.push(Date.now() - at * 1000);
    this.captureLatencies = this.captureLatencies.slice(-200);
  }
}

/** Say who renders: ``view`` (a ServerView or LocalView) and why the server does where it does. */
export function showMode(view) {
  $("mode").textContent = view.mode === "browser" ? `this browser (${view.gpu || "WebGL2"})`
    : `the server${view.why && !["chosen", "auto"].includes(view.why) ? ` (${view.why})` : ""}`;
}

/** The panel for a view on screen: ``header`` (the server's frame header, or the browser renderer's info with
 * render_ms and frame), ``view`` (what drew it: its quality and render time say it), ``own`` (the page's depth
 * switches), ``pose`` (the orbit), ``auto`` (whether D_bnd is the rig's). */
export function showStats(stats, header, view, own, pose, auto) {
  showQuality(view.quality(header), own);
  const now = performance.now();
  stats.arrivals = stats.arrivals.filter((t) => now - t <= 2000);
  stats.latencies = stats.latencies.slice(-50);
  const sorted = [...stats.latencies].sort((a, b) => a - b);
  const pick = (q) => (sorted.length ? sorted[Math.min(sorted.length - 1, Math.floor(q * sorted.length))] : NaN);
  $("fps").textContent = (stats.arrivals.length / 2).toFixed(1);
  $("latency").textContent = sorted.length ? `p50 ${pick(0.5).toFixed(0)} ms · p95 ${pick(0.95).toFixed(0)} ms` : "–";
  $("render").textContent = view.renderText(header);
  if (header.d_bnd !== null && header.d_bnd !== undefined) {
    $("dbnd-value").value = `${Number(header.d_bnd).toPrecision(3)}${auto ? " (auto)" : ""}`;
  }
  $("pose").textContent = `az ${pose.azimuth.toFixed(0)}° el ${pose.elevation.toFixed(0)}° d ${pose.distance.toFixed(2)}`;
  $("depth").textContent = header.depth_found
    ? `${header.depth_found[0].toFixed(2)}–${header.depth_found[1].toFixed(2)} (swept ${header.depth_range[0].toFixed(2)}–${header.depth_range[1].toFixed(2)})`
    : "no surface";
}

/** The quality shown: ``runs`` (the level that ran, or "custom") and ``asked`` (auto, best or fast). */
function showQuality({ runs, asked }, own) {
  if (!runs) return;
  const text = runs === "custom"
    ? `custom: ${own.aggregation ?? "the level's"} depth, occlusions ${own.occlusions ?? "as the level"}`
    : LEVEL_TEXT[runs] ?? runs;
  $("quality-shown").textContent = asked === "auto" ? `${text} (auto)` : text;
}

/** A live set's spread of capture times and its stale cameras (frame header or relayed set header). */
export function showSpread(header) {
  const stale = header.stale && header.stale.length ? ` · stale: ${header.stale.join(", ")}` : "";
  $("spread").textContent = header.spread_ms === null || header.spread_ms === undefined ? `unknown${stale}`
    : `${Number(header.spread_ms).toFixed(1)} ms${stale}`;
}

export function setState(text) { $("state").textContent = text; }
export function notice(text) { $("notice").textContent = text; $("notice").hidden = false; }
export function hideNotice() { $("notice").hidden = true; }
export function showError(text) { $("error").textContent = text; $("error").hidden = false; }
export function hideError() { $("error").hidden = true; }
