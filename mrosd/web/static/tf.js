// The TF tab: the frame tree from /tf and /tf_static as the page receives them (each frame's parent, rate, age,
// static or not), and a top-down view of the frames in a fixed frame chosen on the page, with LaserScan and
// PointCloud2 topics drawn in it (their points from scan.js, moved here by the composed transforms).
import { scanPoints, cloudPoints } from "./scan.js";

// --- transforms: {t: [x, y, z], q: [x, y, z, w]}, mapping child coordinates into the parent's --------------
export const IDENTITY = Object.freeze({ t: [0, 0, 0], q: [0, 0, 0, 1] });

function qmul(a, b) {
  return [
    a[3] * b[0] + a[0] * b[3] + a[1] * b[2] - a[2] * b[1],
    a[3] * b[1] - a[0] * b[2] + a[1] * b[3] + a[2] * b[0],
    a[3] * b[2] + a[0] * b[1] - a[1] * b[0] + a[2] * b[3],
    a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2],
  ];
}
// Rotate p by the unit quaternion q.
export function rotate(q, p) {
  const [x, y, z, w] = q;
  const tx = 2 * (y * p[2] - z * p[1]), ty = 2 * (z * p[0] - x * p[2]), tz = 2 * (x * p[1] - y * p[0]);
  return [p[0] + w * tx + (y * tz - z * ty), p[1] + w * ty + (z * tx - x * tz), p[2] + w * tz + (x * ty - y * tx)];
}
export const apply = (T, p) => { const r = rotate(T.q, p); return [r[0] + T.t[0], r[1] + T.t[1], r[2] + T.t[2]]; };
// a ∘ b: first b, then a (parent_T_mid ∘ mid_T_child = parent_T_child).
export function compose(a, b) {
  const t = apply(a, b.t);
  return { t, q: normalize(qmul(a.q, b.q)) };
}
export function invert(T) {
  const q = [-T.q[0], -T.q[1], -T.q[2], T.q[3]];
  const r = rotate(q, T.t);
  return { t: [-r[0], -r[1], -r[2]], q };
}
function normalize(q) {
  const n = Math.hypot(q[0], q[1], q[2], q[3]);
  return n > 0 && Number.isFinite(n) ? q.map((v) => v / n) : [0, 0, 0, 1];
}
export const yaw = (q) => Math.atan2(2 * (q[3] * q[2] + q[0] * q[1]), 1 - 2 * (q[1] * q[1] + q[2] * q[2]));

// tf2 drops a leading slash from frame ids.
export const frameId = (name) => String(name).replace(/^\/+/, "");

const MAX_DEPTH = 256;
// root_T_frame and the root's name, walking the parents (a loop or a depth beyond MAX_DEPTH ends the walk: null).
export function toRoot(frames, name) {
  let T = IDENTITY, at = name;
  for (let d = 0; d < MAX_DEPTH; d++) {
    const f = frames.get(at);
    if (!f) return { root: at, T };
    T = compose(f.T, T);
    at = f.parent;
  }
  return null;
}
// fixed_T_frame, or null when the two are not in one tree.
export function lookup(frames, fixed, name) {
  const a = toRoot(frames, fixed), b = toRoot(frames, name);
  if (!a || !b || a.root !== b.root) return null;
  return compose(invert(a.T), b.T);
}

// Every frame name (children and parents) with its depth, parents first, siblings by name: the tree as rows.
export function treeRows(frames) {
  const children = new Map(), names = new Set();
  for (const [child, f] of frames) {
    names.add(child); names.add(f.parent);
    if (!children.has(f.parent)) children.set(f.parent, []);
    children.get(f.parent).push(child);
  }
  const rows = [], seen = new Set();
  const walk = (name, depth) => {
    if (seen.has(name)) return;
    seen.add(name); rows.push({ name, depth });
    for (const c of (children.get(name) || []).sort()) walk(c, depth + 1);
  };
  for (const n of [...names].sort()) if (!frames.has(n)) walk(n, 0); // roots
  for (const n of [...names].sort()) walk(n, 0); // what a loop left out
  return rows;
}

// --- the frames as received -----------------------------------------------------------------------------
const RATE_WINDOW_S = 5, RATE_MIN_SPAN_S = 0.5, MAX_FRAMES = 2000;

export class FrameStore {
  constructor() { this.frames = new Map(); }
  // One TransformStamped as received (static: from /tf_static) at page time `now` (s).
  add(ts, isStatic, now) {
    const child = frameId(ts.child_frame_id), parent = frameId(ts.header.frame_id);
    if (!child || child === parent) return;
    let f = this.frames.get(child);
    if (!f) {
      if (this.frames.size >= MAX_FRAMES) return;
      f = { times: [] };
      this.frames.set(child, f);
    }
    const tr = ts.transform.translation, r = ts.transform.rotation;
    f.parent = parent; f.static = isStatic; f.received = now;
    f.stamp = ts.header.stamp.secs + ts.header.stamp.nsecs / 1e9;
    f.T = { t: [tr.x, tr.y, tr.z], q: normalize([r.x, r.y, r.z, r.w]) };
    f.times.push(now);
    while (f.times.length && f.times[0] < now - RATE_WINDOW_S) f.times.shift();
  }
  // Updates per second over the last RATE_WINDOW_S (null: static, or too few updates yet).
  rate(name, now) {
    const f = this.frames.get(name);
    if (!f || f.static) return null;
    const times = f.times.filter((t) => t >= now - RATE_WINDOW_S);
    const span = times.length ? times[times.length - 1] - times[0] : 0;
    if (times.length < 3 || span < RATE_MIN_SPAN_S) return null; // a burst on subscribing is not a rate
    return (times.length - 1) / span;
  }
}

// --- the tab --------------------------------------------------------------------------------------------
const el = (tag, props = {}, ...kids) => { const e = Object.assign(document.createElement(tag), props); e.append(...kids); return e; };
const SIZE = 520;
const SENSOR_TYPES = new Set(["sensor_msgs/LaserScan", "sensor_msgs/PointCloud2"]);

export class TfTab {
  constructor(api, root) {
    this.api = api; this.root = root;
    this.store = new FrameStore();
    this.subs = []; this.sensorSubs = new Map(); this.sensors = new Map(); this.timer = null;
    this.fixed = el("select", { id: "tf-fixed", title: "fixed frame" });
    this.sensorList = el("span", { id: "tf-sensors" });
    this.table = el("table", { id: "tf-tree" }, el("thead", {}, el("tr", {}, ...["Frame", "Parent", "Rate", "Age", ""].map((h) => el("th", {}, h)))), el("tbody"));
    this.canvas = el("canvas", { id: "tf-view", width: SIZE, height: SIZE });
    root.append(
      el("div", { className: "bar" }, el("label", {}, "fixed frame ", this.fixed), this.sensorList),
      el("div", { className: "split" }, this.canvas, el("div", { className: "tf-side" }, this.table)),
    );
  }
  now() { return performance.now() / 1000; }
  show() {
    if (this.on) return; // shown already (a reconnect, a second hash change)
    this.on = true;
    for (const [topic, isStatic] of [["/tf", false], ["/tf_static", true]]) this.follow(topic, isStatic);
    this.channels();
    this.timer = setInterval(() => this.render(), 250);
    this.render();
  }
  hide() {
    this.on = false;
    clearInterval(this.timer); this.timer = null;
    for (const s of this.subs) this.api.unsubscribe(s);
    for (const s of this.sensorSubs.values()) this.api.unsubscribe(s);
    this.subs = []; this.sensorSubs.clear();
  }
  follow(topic, isStatic) {
    if (this.subs.some((s) => s.topic === topic)) return;
    const sub = this.api.subscribe(topic, (msg) => { const now = this.now(); for (const ts of msg.transforms) this.store.add(ts, isStatic, now); });
    if (sub) this.subs.push(sub);
  }
  // The graph changed: follow /tf and /tf_static once they exist, list the scan and cloud topics.
  channels() {
    if (!this.on) return;
    this.follow("/tf", false); this.follow("/tf_static", true);
    const topics = [...this.api.state.byTopic.values()].filter((c) => SENSOR_TYPES.has(c.schemaName)).map((c) => c.topic).sort();
    const have = [...this.sensorList.querySelectorAll("input")].map((i) => i.value);
    if (have.join("\n") === topics.join("\n")) return;
    this.sensorList.replaceChildren(...topics.map((t) => {
      const box = el("input", { type: "checkbox", value: t, checked: this.sensorSubs.has(t) });
      box.addEventListener("change", () => this.toggleSensor(t, box.checked));
      return el("label", { className: "hint" }, box, " " + t);
    }));
  }
  toggleSensor(topic, on) {
    if (!on) { this.api.unsubscribe(this.sensorSubs.get(topic)); this.sensorSubs.delete(topic); this.sensors.delete(topic); return; }
    const type = this.api.state.byTopic.get(topic)?.schemaName;
    const sub = this.api.subscribe(topic, (msg) => {
      try {
        const xyz = type === "sensor_msgs/LaserScan" ? scanPoints(msg) : cloudPoints(msg);
        this.sensors.set(topic, { frame: frameId(msg.header.frame_id), xyz, cloud: type !== "sensor_msgs/LaserScan" });
      } catch (e) { console.warn(topic, e); }
    }, 10);
    if (sub) this.sensorSubs.set(topic, sub);
  }
  render() {
    const now = this.now(), wall = Date.now() / 1000, frames = this.store.frames;
    const rows = treeRows(frames);
    const names = rows.map((r) => r.name);
    const pick = this.fixed, keep = pick.value;
    if ([...pick.options].map((o) => o.value).join("\n") !== names.join("\n")) {
      pick.replaceChildren(...names.map((n) => new Option(n, n)));
      pick.value = names.includes(keep) ? keep : rows.find((r) => r.depth === 0)?.name ?? "";
    }
    this.table.tBodies[0].replaceChildren(...rows.map(({ name, depth }) => {
      const f = frames.get(name), rate = this.store.rate(name, now);
      const age = f && !f.static && f.stamp > 0 ? wall - f.stamp : null;
      const cells = [name, f ? f.parent : "", f ? (f.static ? "static" : rate === null ? "…" : `${rate.toFixed(1)} Hz`) : "", age === null ? "" : `${age.toFixed(2)} s`, f && !f.static && now - f.received > 5 ? "stale" : ""];
      const tr = el("tr", {}, ...cells.map((c) => el("td", {}, c)));
      tr.dataset.frame = name;
      if (rate !== null) tr.dataset.rate = rate.toFixed(3);
      tr.firstChild.style.paddingLeft = `${6 + 14 * depth}px`;
      tr.addEventListener("click", () => { pick.value = name; this.render(); });
      return tr;
    }));
    this.draw(pick.value);
  }
  // The frames (axes: x red, y green) and the sensors' points, from above in the fixed frame, autoscaled.
  draw(fixed) {
    const frames = this.store.frames, ctx = this.canvas.getContext("2d");
    ctx.fillStyle = "#101418"; ctx.fillRect(0, 0, SIZE, SIZE);
    const placed = [];
    for (const { name } of treeRows(frames)) {
      const T = lookup(frames, fixed, name);
      if (T) placed.push({ name, T });
    }
    const clouds = [];
    for (const [topic, s] of this.sensors) {
      const T = lookup(frames, fixed, s.frame) ?? (s.frame === fixed ? IDENTITY : null);
      if (T) clouds.push({ topic, s, T });
    }
    // The view fits what is drawn (frames and points), centred on it; at least 1 m across.
    let lo = [Infinity, Infinity], hi = [-Infinity, -Infinity];
    const grow = (x, y) => { if (Number.isFinite(x) && Number.isFinite(y)) { lo = [Math.min(lo[0], x), Math.min(lo[1], y)]; hi = [Math.max(hi[0], x), Math.max(hi[1], y)]; } };
    for (const p of placed) grow(p.T.t[0], p.T.t[1]);
    const moved = clouds.map(({ s, T }) => {
      const out = new Float64Array(s.xyz.length);
      for (let i = 0; i < s.xyz.length; i += 3) {
        const p = apply(T, [s.xyz[i], s.xyz[i + 1], s.xyz[i + 2]]);
        out[i] = p[0]; out[i + 1] = p[1]; out[i + 2] = p[2];
        grow(p[0], p[1]);
      }
      return { out, cloud: s.cloud };
    });
    if (lo[0] > hi[0]) { lo = [0, 0]; hi = [0, 0]; }
    const mid = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2];
    const r = Math.max(0.5, (hi[0] - lo[0]) / 2, (hi[1] - lo[1]) / 2) * 1.15;
    const c = SIZE / 2, k = (SIZE / 2 - 16) / r;
    const px = (x, y) => [c - (y - mid[1]) * k, c - (x - mid[0]) * k]; // x forward = up, y left = left
    ctx.fillStyle = "#8a97a3"; ctx.font = "12px sans-serif"; ctx.fillText(`${fixed || "(no frames)"} · ${(2 * r).toPrecision(3)} m across`, 6, 14);
    for (const { out, cloud } of moved) {
      ctx.fillStyle = cloud ? "#ffb74d" : "#4fc3f7";
      for (let i = 0; i < out.length; i += 3) {
        if (!Number.isFinite(out[i]) || !Number.isFinite(out[i + 1])) continue;
        const [u, v] = px(out[i], out[i + 1]); ctx.fillRect(u - 1, v - 1, 2, 2);
      }
    }
    const axis = 0.12 * r;
    for (const { name, T } of placed) {
      const [u, v] = px(T.t[0], T.t[1]);
      for (const [dir, colour] of [[[axis, 0, 0], "#e57373"], [[0, axis, 0], "#81c784"]]) {
        const e = apply(T, dir), [eu, ev] = px(e[0], e[1]);
        ctx.strokeStyle = colour; ctx.beginPath(); ctx.moveTo(u, v); ctx.lineTo(eu, ev); ctx.stroke();
      }
      ctx.fillStyle = "#dde3e8"; ctx.fillText(name.length > 40 ? "…" + name.slice(-39) : name, u + 4, v - 4);
    }
    this.drawn = { fixed, frames: placed.map((p) => ({ name: p.name, t: p.T.t, yaw: yaw(p.T.q) })), points: moved.reduce((n, m) => n + m.out.length / 3, 0) };
  }
}
