// LaserScan and PointCloud2 drawn from above (x forward = up, y left = left), autoscaled, onto a canvas.
const SIZE = 480, MAX_POINTS = 200000;

function frame(canvas, points, colour) {
  canvas.width = SIZE; canvas.height = SIZE;
  const ctx = canvas.getContext("2d");
  ctx.fillStyle = "#101418"; ctx.fillRect(0, 0, SIZE, SIZE);
  let r = 0;
  for (let i = 0; i < points.length; i += 2) {
    const d = Math.max(Math.abs(points[i]), Math.abs(points[i + 1]));
    if (Number.isFinite(d) && d > r) r = d;
  }
  r = r || 1;
  const s = (SIZE / 2 - 10) / r, c = SIZE / 2;
  ctx.strokeStyle = "#2a323a"; ctx.beginPath(); ctx.arc(c, c, (SIZE / 2 - 10), 0, 2 * Math.PI); ctx.stroke();
  ctx.fillStyle = "#8a97a3"; ctx.font = "12px sans-serif"; ctx.fillText(`${r.toPrecision(3)} m`, c + 4, 14);
  ctx.fillStyle = "#e57373"; ctx.fillRect(c - 3, c - 3, 6, 6); // the sensor
  for (let i = 0, k = 0; i < points.length; i += 2, k++) {
    const x = points[i], y = points[i + 1];
    if (!Number.isFinite(x) || !Number.isFinite(y)) continue;
    ctx.fillStyle = colour(k);
    ctx.fillRect(c - y * s - 1, c - x * s - 1, 2, 2);
  }
}

// A scan's points in its own frame, as x, y, z triplets (z = 0); readings outside [range_min, range_max] left out.
export function scanPoints(msg) {
  const out = [];
  msg.ranges.forEach((range, i) => {
    if (!(range >= msg.range_min && range <= msg.range_max)) return;
    const a = msg.angle_min + i * msg.angle_increment;
    out.push(range * Math.cos(a), range * Math.sin(a), 0);
  });
  return Float64Array.from(out);
}

const xyOf = (xyz) => { const xy = new Float64Array(2 * (xyz.length / 3)); for (let i = 0, k = 0; i < xyz.length; i += 3, k += 2) { xy[k] = xyz[i]; xy[k + 1] = xyz[i + 1]; } return xy; };

export function drawScan(canvas, msg) {
  const pts = xyOf(scanPoints(msg));
  frame(canvas, pts, () => "#4fc3f7");
  return pts.length / 2;
}

const READ = { 7: ["getFloat32", 4], 8: ["getFloat64", 8] };

// A cloud's points (float x, y and z when present: 0 without) as x, y, z triplets, at most MAX_POINTS.
export function cloudPoints(msg) {
  const field = (n) => msg.fields.find((f) => f.name === n && READ[f.datatype]);
  const fx = field("x"), fy = field("y"), fz = field("z");
  if (!fx || !fy) throw new Error("PointCloud2 without float x and y fields");
  const view = new DataView(msg.data.buffer, msg.data.byteOffset, msg.data.byteLength);
  const le = !msg.is_bigendian;
  const n = Math.min(msg.width * msg.height, Math.floor(msg.data.length / msg.point_step), MAX_POINTS);
  const xyz = new Float64Array(3 * n);
  for (let i = 0; i < n; i++) {
    const o = i * msg.point_step;
    xyz[3 * i] = view[READ[fx.datatype][0]](o + fx.offset, le);
    xyz[3 * i + 1] = view[READ[fy.datatype][0]](o + fy.offset, le);
    xyz[3 * i + 2] = fz ? view[READ[fz.datatype][0]](o + fz.offset, le) : 0;
  }
  return xyz;
}

export function drawCloud(canvas, msg) {
  const xyz = cloudPoints(msg), n = xyz.length / 3;
  let lo = Infinity, hi = -Infinity;
  for (let i = 2; i < xyz.length; i += 3) { if (xyz[i] < lo) lo = xyz[i]; if (xyz[i] > hi) hi = xyz[i]; }
  const span = hi > lo ? hi - lo : 1;
  frame(canvas, xyOf(xyz), (k) => `hsl(${240 - 240 * ((xyz[3 * k + 2] - lo) / span)},80%,60%)`);
  return n;
}
