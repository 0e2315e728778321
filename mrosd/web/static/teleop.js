// The Teleop panel: an on-screen joystick (pointer drag) and the arrow keys publish geometry_msgs/Twist at 10 Hz
// to a chosen topic (default /cmd_vel) within chosen limits. Letting go, the page losing focus or being hidden,
// and the tab closing each publish one zero Twist. Should the connection drop instead, the daemon publishes the
// zero itself (mrosd/web/deadman.py).
import { parseDefinition, serialize } from "./ros1.js";

export const TWIST_DEF = "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n"
  + "================================================================================\n"
  + "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n";
export const RATE_HZ = 10;
const clamp1 = (v) => Math.max(-1, Math.min(1, Number.isFinite(v) ? v : 0));

// The command for a stick at (sx, sy) in [-1, 1] (right and down positive, as on screen): up drives forward
// (linear.x), left turns left (angular.z positive, ROS's counter-clockwise).
export function twistOf(sx, sy, limits) {
  return { linear: { x: -clamp1(sy) * limits.linear, y: 0, z: 0 }, angular: { x: 0, y: 0, z: -clamp1(sx) * limits.angular } };
}
// The stick position the held arrow keys stand for.
export function keysStick(keys) {
  return [(keys.has("ArrowRight") ? 1 : 0) - (keys.has("ArrowLeft") ? 1 : 0), (keys.has("ArrowDown") ? 1 : 0) - (keys.has("ArrowUp") ? 1 : 0)];
}
// Limits as typed: finite, non-negative, at most `cap` (a typo must not command 100 m/s).
export function limitOf(text, fallback, cap = 10) {
  const v = Number(text);
  return Number.isFinite(v) && v >= 0 ? Math.min(v, cap) : fallback;
}
export const isZero = (t) => !t.linear.x && !t.linear.y && !t.linear.z && !t.angular.x && !t.angular.y && !t.angular.z;

const el = (tag, props = {}, ...kids) => { const e = Object.assign(document.createElement(tag), props); e.append(...kids); return e; };
const ZERO = twistOf(0, 0, { linear: 0, angular: 0 });
const KEYS = new Set(["ArrowUp", "ArrowDown", "ArrowLeft", "ArrowRight"]);

export class TeleopTab {
  constructor(api, root) {
    this.api = api; this.on = false; this.def = parseDefinition("geometry_msgs/Twist", TWIST_DEF);
    this.chan = null; this.chanTopic = null; this.timer = null; this.stick = [0, 0]; this.keys = new Set();
    this.dragging = false; this.sent = 0; this.zeros = 0; this.lastMoving = false;
    this.topic = el("input", { id: "teleop-topic", value: "/cmd_vel", size: 16 });
    this.linear = el("input", { id: "teleop-linear", type: "number", value: "0.5", step: "0.1", min: "0" });
    this.angular = el("input", { id: "teleop-angular", type: "number", value: "1.0", step: "0.1", min: "0" });
    this.knob = el("div", { className: "knob" });
    this.pad = el("div", { id: "teleop-pad", className: "pad", tabIndex: 0, title: "drag, or hold the arrow keys" }, this.knob);
    this.statusEl = el("div", { id: "teleop-status", className: "hint" }, "idle");
    root.append(
      el("div", { className: "bar" },
        el("label", {}, "topic ", this.topic), el("label", {}, "linear m/s ", this.linear), el("label", {}, "angular rad/s ", this.angular)),
      this.pad, this.statusEl,
      el("p", { className: "hint" }, "Drag the stick or hold the arrow keys: geometry_msgs/Twist at 10 Hz. Letting go, leaving the page or closing the tab sends zero; if the connection drops while driving, mrosd sends it."),
    );
    this.topic.addEventListener("change", () => { this.release(); this.drop(); });
    this.pad.addEventListener("pointerdown", (e) => {
      this.dragging = true;
      try { this.pad.setPointerCapture(e.pointerId); } catch { /* a synthetic pointer */ }
      this.move(e); this.drive();
    });
    this.pad.addEventListener("pointermove", (e) => { if (this.dragging) this.move(e); });
    for (const ev of ["pointerup", "pointercancel", "lostpointercapture"]) this.pad.addEventListener(ev, () => { if (this.dragging) { this.dragging = false; this.stick = [0, 0]; this.release(); } });
    window.addEventListener("keydown", (e) => {
      if (!this.on || !KEYS.has(e.key) || e.target instanceof HTMLInputElement || e.target instanceof HTMLSelectElement) return;
      e.preventDefault(); this.keys.add(e.key); this.stick = keysStick(this.keys); this.drive();
    });
    window.addEventListener("keyup", (e) => {
      if (!this.keys.delete(e.key)) return;
      this.stick = keysStick(this.keys);
      if (!this.keys.size && !this.dragging) this.release();
    });
    window.addEventListener("blur", () => this.release());
    document.addEventListener("visibilitychange", () => { if (document.visibilityState === "hidden") this.release(); });
    window.addEventListener("pagehide", () => this.release());
  }
  show() { this.on = true; this.ensure(); }
  hide() { this.release(); this.on = false; }
  disconnected() { this.stopTimer(); this.chan = null; this.chanTopic = null; this.dragging = false; this.keys.clear(); this.stick = [0, 0]; }
  limits() { return { linear: limitOf(this.linear.value, 0.5), angular: limitOf(this.angular.value, 1.0) }; }
  // Advertise the chosen topic (ahead of driving, so its subscribers are connected when the first command goes).
  ensure() {
    const topic = this.topic.value.trim();
    if (this.chan !== null && this.chanTopic === topic) return true;
    this.drop();
    if (!topic.startsWith("/")) { this.statusEl.textContent = "the topic must be a global name (/cmd_vel)"; return false; }
    this.chan = this.api.advertise(topic, "geometry_msgs/Twist", TWIST_DEF);
    this.chanTopic = topic;
    return this.chan !== null;
  }
  drop() { if (this.chan !== null) this.api.unadvertise(this.chan); this.chan = null; this.chanTopic = null; }
  move(e) {
    const r = this.pad.getBoundingClientRect(), half = r.width / 2;
    let sx = (e.clientX - r.left - half) / half, sy = (e.clientY - r.top - half) / half;
    const n = Math.hypot(sx, sy);
    if (n > 1) { sx /= n; sy /= n; }
    this.stick = [sx, sy];
    this.knob.style.transform = `translate(${sx * half * 0.8}px, ${sy * half * 0.8}px)`;
  }
  publish(twist) {
    if (!this.ensure()) return;
    this.api.publish(this.chan, serialize(this.def, twist));
    this.sent++;
    if (isZero(twist)) this.zeros++;
    this.lastMoving = !isZero(twist);
    const l = twist.linear.x.toFixed(2), a = twist.angular.z.toFixed(2);
    this.statusEl.textContent = `${this.chanTopic}: linear.x ${l} m/s, angular.z ${a} rad/s (${this.sent} sent)`;
    this.statusEl.dataset.linear = l; this.statusEl.dataset.angular = a;
  }
  // Start (or keep) publishing the stick's command at RATE_HZ.
  drive() {
    if (!this.on) return;
    this.publish(twistOf(...this.stick, this.limits()));
    if (this.timer === null) this.timer = setInterval(() => this.publish(twistOf(...this.stick, this.limits())), 1000 / RATE_HZ);
  }
  stopTimer() { if (this.timer !== null) clearInterval(this.timer); this.timer = null; }
  // Let go: stop publishing and send one zero (if anything moved since the last zero).
  release() {
    const wasDriving = this.timer !== null || this.lastMoving;
    this.stopTimer(); this.keys.clear(); this.dragging = false; this.stick = [0, 0];
    this.knob.style.transform = "";
    if (wasDriving && this.chan !== null) this.publish(ZERO);
  }
}
