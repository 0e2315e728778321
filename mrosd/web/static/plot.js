// A time plot of one numeric field on a canvas: the last `keep` seconds, autoscaled.
export class Plot {
  constructor(canvas, keep = 30) { this.canvas = canvas; this.keep = keep; this.points = []; this.label = ""; }

  add(t, v) {
    if (!Number.isFinite(v)) return;
    this.points.push([t, v]);
    const cut = t - this.keep;
    let drop = 0;
    while (drop < this.points.length && this.points[drop][0] < cut) drop++;
    if (drop) this.points.splice(0, drop);
  }

  reset(label) { this.points = []; this.label = label; }

  draw() {
    const c = this.canvas, ctx = c.getContext("2d");
    const w = (c.width = c.clientWidth || 600), h = (c.height = c.clientHeight || 240);
    ctx.fillStyle = "#101418"; ctx.fillRect(0, 0, w, h);
    ctx.fillStyle = "#9ab"; ctx.font = "12px sans-serif";
    ctx.fillText(this.label || "click a number in the message tree to plot it", 8, 16);
    const pts = this.points;
    if (pts.length < 2) return;
    let lo = Infinity, hi = -Infinity;
    for (const [, v] of pts) { if (v < lo) lo = v; if (v > hi) hi = v; }
    if (hi === lo) { hi += 1; lo -= 1; }
    const t1 = pts[pts.length - 1][0], t0 = t1 - this.keep;
    const x = (t) => 50 + ((t - t0) / this.keep) * (w - 60);
    const y = (v) => h - 20 - ((v - lo) / (hi - lo)) * (h - 45);
    ctx.fillText(hi.toPrecision(5), 2, 32); ctx.fillText(lo.toPrecision(5), 2, h - 20);
    ctx.fillText(`last ${pts[pts.length - 1][1].toPrecision(6)}`, w - 140, 16);
    ctx.strokeStyle = "#4fc3f7"; ctx.lineWidth = 1.5; ctx.beginPath();
    pts.forEach(([t, v], i) => (i ? ctx.lineTo(x(t), y(v)) : ctx.moveTo(x(t), y(v))));
    ctx.stroke();
  }
}
