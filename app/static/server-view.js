// A view the server renders (see app/routers/rig_sockets.py for the socket protocol): each viewpoint goes out as
// JSON text, each frame comes back as a binary message (framing.js: a header, then the JPEG) and is drawn into the
// page's 2D canvas. At most one viewpoint is in flight; changes made meanwhile go out, as one viewpoint, when its
// frame arrives. The page drives it as it drives a LocalView (local-view.js): start, sessionReady, binary, failed,
// show, quality, renderText, dispose.
import { unpackMessage } from "./framing.js";
import { showSpread } from "./status.js";

const STUCK_MS = 10000; // a viewpoint unanswered this long no longer holds the next one back

export class ServerView {
  /** page: the viewer page (viewer.js: its socket, controls, orbit, stats, frame and callbacks); canvas: the 2D
   * canvas it draws in; why: why the server renders ("chosen", "auto" or the browser's reason). */
  constructor(page, canvas, why) {
    Object.assign(this, { page, canvas, why, mode: "server" });
    this.context = canvas.getContext("2d");
    this.ready = false; // the session runs: viewpoints may go out
    this.dirty = false; // a change waits to be sent
    this.nextId = 1;
    this.inFlight = null; // the id of the viewpoint whose frame has not come
    this.inFlightAt = 0;
    this.sentAt = new Map(); // id -> when it was asked for
    this.lastHeader = null;
  }

  /** The hello came: the session says when it is ready. */
  async start() {}

  /** The session runs: show the view. */
  sessionReady() {
    this.ready = true;
    this.page.onReady();
  }

  /** Ask for the view the controls now describe, unless one is in flight (then when it arrives). */
  show() {
    this.dirty = true;
    const ws = this.page.socket;
    const stuck = this.inFlight !== null && performance.now() - this.inFlightAt > STUCK_MS;
    if (!this.ready || !ws || ws.readyState !== WebSocket.OPEN || (this.inFlight !== null && !stuck)) return;
    const vp = this.viewpoint();
    ws.send(JSON.stringify(vp));
    this.sentAt.set(vp.id, this.page.stats.takeChange() ?? performance.now());
    Object.assign(this, { inFlight: vp.id, inFlightAt: performance.now(), dirty: false });
  }

  /** The viewpoint message (workers/streaming/params.py Viewpoint) of the controls and the orbit now; what it leaves
   * out (field of view, JPEG quality, coarse_to_fine) is the server's default. */
  viewpoint() {
    const { controls, orbit } = this.page;
    const [width, height] = controls.size;
    return {
      type: "view", id: this.nextId++, width, height, orbit: orbit.pose, ...controls.pageOptions(),
      ...controls.depthOptions(), render_quality: controls.quality, frame: this.page.frame, overlay: controls.overlay,
    };
  }

  /** A frame: its header and JPEG, drawn. */
  async binary(buffer) {
    const arrived = performance.now();
    const { header, payload } = unpackMessage(buffer);
    const sent = this.sentAt.get(header.id);
    for (const id of this.sentAt.keys()) if (id <= header.id) this.sentAt.delete(id);
    const bitmap = await createImageBitmap(new Blob([payload], { type: "image/jpeg" }));
    if (this.canvas.width !== header.width || this.canvas.height !== header.height) {
      this.canvas.width = header.width;
      this.canvas.height = header.height;
    }
    this.context.drawImage(bitmap, 0, 0);
    bitmap.close();
    this.page.stats.shown(sent ?? null, arrived);
    this.lastHeader = header;
    if (header.frame === "live") {
      this.page.stats.captured(header.captured);
      showSpread(header);
    }
    this.page.onShown(header);
    if (header.id === this.inFlight) this.landed();
  }

  /** An error the socket sent: a viewpoint that failed is no longer in flight. */
  failed(message) {
    if (message.id !== undefined && message.id === this.inFlight) this.landed();
  }

  landed() {
    this.inFlight = null;
    if (this.dirty) this.show();
  }

  /** The quality level that ran and the one asked for, as the frame header says. */
  quality(header) {
    return { runs: header.quality, asked: header.quality_asked };
  }

  renderText(header) {
    return `${header.render_ms.toFixed(0)} ms${header.reshaded ? " (re-shaded)" : ""} + JPEG ${header.encode_ms.toFixed(0)} ms`;
  }

  dispose() {
    this.ready = false;
  }
}
