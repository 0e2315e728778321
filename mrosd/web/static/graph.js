// The node graph as SVG: publishers -> topic -> subscribers, laid out in three columns.
const NS = "http://www.w3.org/2000/svg";
const el = (name, attrs, text) => {
  const e = document.createElementNS(NS, name);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
};

// Cut a label that does not fit its shape to "…" and its end (the full name is the shape's title). Measured
// when the SVG is drawn; estimated from the length (11 px font) when it is not (a hidden view measures 0).
function fit(text, label, width) {
  const measure = () => text.getComputedTextLength();
  if (measure() === 0) {
    const chars = Math.floor(width / 6.6);
    if (label.length > chars) text.textContent = "…" + label.slice(-(chars - 1));
    return;
  }
  if (measure() <= width) return;
  let lo = 1, hi = label.length - 1; // the longest tail that fits, by halving
  while (lo < hi) {
    const mid = Math.ceil((lo + hi) / 2);
    text.textContent = "…" + label.slice(-mid);
    if (measure() <= width) lo = mid; else hi = mid - 1;
  }
  text.textContent = "…" + label.slice(-lo);
}

// pubs/subs: Map(topic -> Set(node)); dead: Set(node); onNode(name) when a node is clicked.
export function drawGraph(svg, pubs, subs, dead, onNode, hide = new Set()) {
  svg.replaceChildren();
  const topics = [...new Set([...pubs.keys(), ...subs.keys()])].filter((t) => !hide.has(t)).sort();
  const publishers = new Set(), subscribers = new Set();
  for (const t of topics) {
    for (const n of pubs.get(t) || []) publishers.add(n);
    for (const n of subs.get(t) || []) subscribers.add(n);
  }
  const left = [...publishers].sort();
  const right = [...subscribers].filter((n) => !publishers.has(n)).sort();
  const rowH = 34, W = 900;
  const rows = Math.max(left.length, topics.length, right.length, 1);
  svg.setAttribute("viewBox", `0 0 ${W} ${rows * rowH + 20}`);
  svg.style.minHeight = `${Math.min(rows * rowH + 20, 2000)}px`;
  const pos = new Map();
  const place = (names, x, kind) => names.forEach((n, i) => pos.set(kind + n, [x, 20 + i * rowH + ((rows - names.length) * rowH) / 2]));
  place(left, 110, "n"); place(topics, 450, "t"); place(right, 790, "n");
  const edges = el("g", { class: "edges" });
  svg.append(edges);
  const edge = (a, b) => {
    const [x1, y1] = a, [x2, y2] = b, mx = (x1 + x2) / 2;
    edges.append(el("path", { d: `M${x1},${y1} C${mx},${y1} ${mx},${y2} ${x2},${y2}`, class: "edge" }));
  };
  for (const t of topics) {
    const tp = pos.get("t" + t);
    for (const n of pubs.get(t) || []) edge([pos.get("n" + n)[0] + 100, pos.get("n" + n)[1]], [tp[0] - 120, tp[1]]);
    for (const n of subs.get(t) || []) {
      const np = pos.get("n" + n);
      if (np[0] > tp[0]) edge([tp[0] + 120, tp[1]], [np[0] - 100, np[1]]);
      else edge([tp[0] + 120, tp[1]], [np[0] + 100, np[1] + 6]);
    }
  }
  const box = (key, label, kind, w) => {
    const [x, y] = pos.get(key);
    const g = el("g", { class: `${kind}${dead.has(label) ? " dead" : ""}`, "data-name": label, transform: `translate(${x},${y})` });
    g.append(el(kind === "node" ? "ellipse" : "rect", kind === "node"
      ? { rx: w, ry: 13 } : { x: -w, y: -12, width: 2 * w, height: 24, rx: 3 }));
    const text = el("text", { "text-anchor": "middle", y: 4 }, label);
    g.append(text);
    g.append(el("title", {}, label + (dead.has(label) ? " (not answering)" : "")));
    if (kind === "node") g.addEventListener("click", () => onNode(label));
    svg.append(g);
    fit(text, label, kind === "node" ? 2 * w - 28 : 2 * w - 10);
  };
  for (const n of [...left, ...right]) box("n" + n, n, "node", 100);
  for (const t of topics) box("t" + t, t, "topic", 120);
}
