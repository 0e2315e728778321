// sensor_msgs/Image and CompressedImage onto a canvas.

// Turbo-like false colour for depth: 0 (no reading) stays black.
function falseColour(t) {
  const r = Math.max(0, Math.min(1, 1.5 - Math.abs(4 * t - 3)));
  const g = Math.max(0, Math.min(1, 1.5 - Math.abs(4 * t - 2)));
  const b = Math.max(0, Math.min(1, 1.5 - Math.abs(4 * t - 1)));
  return [r * 255, g * 255, b * 255];
}

// Fill an ImageData from an Image message; returns null (with a reason) for encodings not drawn.
export function imageToRgba(msg, rgba) {
  const { width: w, height: h, step, data, encoding } = msg;
  const enc = encoding.toLowerCase();
  const px = rgba.data;
  if (enc === "mono8" || enc === "8uc1") {
    for (let y = 0; y < h; y++) for (let x = 0; x < w; x++) {
      const v = data[y * step + x], i = (y * w + x) * 4;
      px[i] = px[i + 1] = px[i + 2] = v; px[i + 3] = 255;
    }
    return true;
  }
  const layouts = { rgb8: [3, 0, 1, 2, -1], bgr8: [3, 2, 1, 0, -1], rgba8: [4, 0, 1, 2, 3], bgra8: [4, 2, 1, 0, 3],
    "8uc3": [3, 2, 1, 0, -1], "8uc4": [4, 2, 1, 0, 3] };
  const lay = layouts[enc];
  if (lay) {
    const [n, r, g, b, a] = lay;
    for (let y = 0; y < h; y++) {
      let s = y * step, i = y * w * 4;
      for (let x = 0; x < w; x++, s += n, i += 4) {
        px[i] = data[s + r]; px[i + 1] = data[s + g]; px[i + 2] = data[s + b]; px[i + 3] = a < 0 ? 255 : data[s + a];
      }
    }
    return true;
  }
  if (enc === "16uc1" || enc === "mono16") {
    const view = new DataView(data.buffer, data.byteOffset, data.byteLength);
    const le = !msg.is_bigendian;
    let lo = Infinity, hi = 0;
    for (let y = 0; y < h; y++) for (let x = 0; x < w; x++) {
      const v = view.getUint16(y * step + 2 * x, le);
      if (v) { if (v < lo) lo = v; if (v > hi) hi = v; }
    }
    const span = hi > lo ? hi - lo : 1;
    for (let y = 0; y < h; y++) for (let x = 0; x < w; x++) {
      const v = view.getUint16(y * step + 2 * x, le), i = (y * w + x) * 4;
      const [r, g, b] = v ? falseColour((v - lo) / span) : [0, 0, 0];
      px[i] = r; px[i + 1] = g; px[i + 2] = b; px[i + 3] = 255;
    }
    return true;
  }
  return false;
}

export class ImageView {
  constructor(canvas) { this.canvas = canvas; this.ctx = canvas.getContext("2d"); this.frames = 0; this.busy = false; }

  drawRaw(msg) {
    const { width: w, height: h } = msg;
    if (!w || !h || msg.data.length < msg.step * h) throw new Error(`image ${w}x${h} step ${msg.step}: data too short`);
    if (this.canvas.width !== w || this.canvas.height !== h) { this.canvas.width = w; this.canvas.height = h; this.rgba = null; }
    this.rgba = this.rgba || this.ctx.createImageData(w, h);
    if (!imageToRgba(msg, this.rgba)) throw new Error(`encoding ${msg.encoding} is not drawn`);
    this.ctx.putImageData(this.rgba, 0, 0);
    this.frames++;
  }

  // Compressed: decoded by the browser as sent (JPEG/PNG), one at a time. A frame arriving meanwhile waits as
  // the next (a newer one replaces it: its promise gives false), so a decode that takes most of a frame period
  // does not halve the rate. Resolves true once this frame is drawn.
  drawCompressed(msg) {
    return new Promise((resolve, reject) => {
      if (this.busy) {
        if (this.pending) this.pending.resolve(false);
        this.pending = { msg, resolve, reject };
        return;
      }
      this.busy = true;
      this._decode(msg).then(() => resolve(true), reject).finally(() => {
        this.busy = false;
        const next = this.pending;
        this.pending = null;
        if (next) this.drawCompressed(next.msg).then(next.resolve, next.reject);
      });
    });
  }

  async _decode(msg) {
    const fmt = msg.format.toLowerCase().includes("png") ? "image/png" : "image/jpeg";
    const bitmap = await createImageBitmap(new Blob([msg.data], { type: fmt }));
    if (this.canvas.width !== bitmap.width || this.canvas.height !== bitmap.height) {
      this.canvas.width = bitmap.width; this.canvas.height = bitmap.height;
    }
    this.ctx.drawImage(bitmap, 0, 0);
    bitmap.close();
    this.frames++;
  }
}

// Whether a raw Image topic T is shown from T/compressed (made by mrosd, or image_transport's): ?images=raw or
// ?images=compressed in the page's URL decides; otherwise compressed unless the page was loaded over loopback
// (the browser on the robot itself: any link carries raw frames there).
export function preferCompressed(loc = location) {
  const asked = new URLSearchParams(loc.search).get("images");
  if (asked === "raw" || asked === "compressed") return asked === "compressed";
  return !["127.0.0.1", "localhost", "[::1]", "::1"].includes(loc.hostname);
}

// An image view's frames per second and age (now - header.stamp) as drawn. The stamp is on the robot's clock,
// the browser's clock may differ: each message's receipt time (messageData's timestamp, the daemon's clock)
// bounds the offset, offset >= receipt - arrival, with equality for a message that took no time on the way;
// the largest of the last 64 is taken, so the age shown includes the link's delay above its fastest message.
export class ImageMeter {
  constructor() { this.reset(); }
  reset() { this.offsets = []; this.offsetMs = 0; this.times = []; this.fps = 0; this.ageMs = null; }
  // a message arrived: its receipt time on the daemon's clock (ms), now on the browser's (ms)
  arrived(receiptMs, nowMs = Date.now()) {
    this.offsets.push(receiptMs - nowMs);
    if (this.offsets.length > 64) this.offsets.shift();
    this.offsetMs = Math.max(...this.offsets);
  }
  // a frame was drawn: its header.stamp ({secs, nsecs}); returns the age in ms on the daemon's clock
  drawn(stamp, nowMs = Date.now()) {
    const t = performance.now();
    this.times.push(t);
    while (this.times.length && this.times[0] < t - 1000) this.times.shift();
    this.fps = this.times.length;
    if (stamp && (stamp.secs || stamp.nsecs)) this.ageMs = nowMs + this.offsetMs - (stamp.secs * 1e3 + stamp.nsecs / 1e6);
    return this.ageMs;
  }
  text(mode) {
    const age = this.ageMs === null ? "age ?" : `age ${Math.round(this.ageMs)} ms`;
    return `${this.fps} fps · ${age}${mode ? " · " + mode : ""}`;
  }
}
