// mrosd's page: one Foxglove WebSocket client (plus mrosd's x-mrosd.* ops) showing the graph, topics,
// a topic's live message, a plot, images and /rosout. Everything is decoded here from the raw ROS 1 bodies.
import { parseDefinition, deserialize, serialize, defaultValue } from "./ros1.js";
import { ImageView, ImageMeter, preferCompressed } from "./image.js";
import { Plot } from "./plot.js";
import { drawGraph } from "./graph.js";
import { drawScan, drawCloud } from "./scan.js";
import { TfTab } from "./tf.js";
import { ActionsTab } from "./actions.js";
import { ReconfigureTab } from "./reconfigure.js";
import { TeleopTab } from "./teleop.js";

const $ = (s) => document.querySelector(s);
const TREE_HZ = 20, IMAGE_HZ = 30, MAX_ARRAY = 32, MAX_LOG = 1000;
const state = {
  channels: new Map(), byTopic: new Map(), pubs: new Map(), subs: new Map(), dead: new Set(),
  stats: new Map(), nextSub: 1, mine: new Map(), view: "graph", current: null, plotPath: null, open: new Set(),
  log: [], rosoutSub: null, services: new Map(), calls: new Map(), nextCall: 1,
  // the daemon's own web node (serverInfo's metadata): it subscribes to what the page measures and views
  hubNode: "/mrosd_web",
};
const plot = new Plot($("#plot"));
const images = new ImageView($("#image"));
const meter = new ImageMeter();
// Per raw Image topic: "raw" or "compressed" as the user toggled it, and the rate limit asked (Hz).
const imageChoice = { mode: new Map(), rate: new Map() };
// For tests and the curious: what the page has drawn.
window.mrosdPage = { state, plot, images, meter, treeUpdates: 0, decodeErrors: 0 };

const params = new URLSearchParams(location.search);
const wsUrl = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/${params.has("token") ? "?token=" + encodeURIComponent(params.get("token")) : ""}`;
let ws;
const send = (obj) => ws && ws.readyState === 1 && ws.send(JSON.stringify(obj));

function connect() {
  ws = new WebSocket(wsUrl, ["foxglove.websocket.v1"]);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => { $("#conn").textContent = "connected"; $("#conn").className = "ok"; send({ op: "subscribeConnectionGraph" }); send({ op: "x-mrosd.subscribeDelivery" }); show(state.view); };
  ws.onclose = () => {
    $("#conn").textContent = "disconnected: retrying"; $("#conn").className = "bad";
    tabsDisconnected();
    state.channels.clear(); state.byTopic.clear(); state.services.clear(); state.calls.clear(); state.mine.clear(); state.current = null; state.rosoutSub = null;
    setTimeout(connect, 2000);
  };
  ws.onmessage = (ev) => (typeof ev.data === "string" ? onJson(JSON.parse(ev.data)) : onBinary(ev.data));
}

function onJson(m) {
  switch (m.op) {
    case "serverInfo":
      if (m.metadata && m.metadata.node) state.hubNode = m.metadata.node;
      break;
    case "advertise":
      for (const c of m.channels) { state.channels.set(c.id, c); state.byTopic.set(c.topic, c); }
      refreshTopicPick(); renderTopics(); if (state.view === "log") ensureRosout();
      tabsChannels();
      break;
    case "unadvertise":
      for (const id of m.channelIds) { const c = state.channels.get(id); if (c) state.byTopic.delete(c.topic); state.channels.delete(id); }
      refreshTopicPick(); renderTopics(); tabsChannels();
      break;
    case "connectionGraphUpdate":
      for (const t of m.publishedTopics || []) state.pubs.set(t.name, new Set(t.publisherIds));
      for (const t of m.subscribedTopics || []) state.subs.set(t.name, new Set(t.subscriberIds));
      for (const t of m.removedTopics || []) { state.pubs.delete(t); state.subs.delete(t); }
      renderGraph(); renderTopics();
      break;
    case "x-mrosd.topicStats":
      for (const s of m.topics) state.stats.set(s.topic, s);
      renderTopics();
      break;
    case "x-mrosd.delivery": // this page's own subscriptions: what the daemon dropped for it (slow link)
      state.drops = new Map(m.subscriptions.filter((d) => d.dropped).map((d) => [d.topic, d.dropped]));
      renderTopics();
      break;
    case "x-mrosd.nodeDetails":
      if (m.alive === false) state.dead.add(m.node); else if (m.alive) state.dead.delete(m.node);
      if (m.id === "probe") renderGraphSoon(); else showNode(m);
      break;
    case "advertiseServices":
      for (const sv of m.services) state.services.set(sv.id, sv);
      refreshServices(); tabsChannels();
      break;
    case "unadvertiseServices":
      for (const id of m.serviceIds) state.services.delete(id);
      refreshServices(); tabsChannels();
      break;
    case "serviceCallFailure": {
      if (tabCallDone(m.callId, null, m.message)) break;
      const call = state.calls.get(m.callId);
      if (call) { state.calls.delete(m.callId); $("#service-status").textContent = "failed: " + m.message; }
      break;
    }
    case "parameterValues": if (m.id === "page") renderParams(m.parameters); break;
    case "x-mrosd.imageSettings": showImageSettings(m); break;
    case "status": if (m.level >= 2) console.warn("mrosd:", m.message); break;
  }
}

function onBinary(buf) {
  const v = new DataView(buf);
  if (v.getUint8(0) === 3) return onServiceResponse(v, buf);
  if (v.getUint8(0) !== 1) return;
  const sub = state.mine.get(v.getUint32(1, true));
  if (!sub) return;
  const stampNs = Number(v.getBigUint64(5, true));
  let msg;
  try { msg = deserialize(sub.def, new Uint8Array(buf, 13)); } catch (e) { window.mrosdPage.decodeErrors++; console.warn(sub.topic, e); return; }
  sub.handler(msg, stampNs / 1e9);
}

function subscribe(topic, handler, maxRate) {
  const c = state.byTopic.get(topic);
  if (!c) return null;
  const id = state.nextSub++;
  const sub = { id, topic, def: parseDefinition(c.schemaName, c.schema), handler, type: c.schemaName };
  state.mine.set(id, sub);
  send({ op: "subscribe", subscriptions: [{ id, channelId: c.id }] });
  if (maxRate) send({ op: "x-mrosd.throttle", subscriptionId: id, maxRate });
  return sub;
}
function unsubscribe(sub) { if (sub && state.mine.delete(sub.id)) send({ op: "unsubscribe", subscriptionIds: [sub.id] }); }

// --- views -----------------------------------------------------------------------------------------
function show(view) {
  if (state.view === "topics" && view !== "topics") send({ op: "x-mrosd.unsubscribeStats" });
  if (state.view === "topic" && view !== "topic") { unsubscribe(state.current); state.current = null; }
  if (state.view === "log" && view !== "log") { unsubscribe(state.rosoutSub); state.rosoutSub = null; }
  if (tabs[state.view] && state.view !== view) tabs[state.view].hide();
  state.view = view;
  document.querySelectorAll("nav button").forEach((b) => b.classList.toggle("on", b.dataset.view === view));
  document.querySelectorAll(".view").forEach((s) => s.classList.toggle("on", s.id === "view-" + view));
  if (view === "topics") send({ op: "x-mrosd.subscribeStats" });
  if (view === "topic") openTopic($("#topic-pick").value);
  if (view === "log") ensureRosout();
  if (view === "params") send({ op: "getParameters", parameterNames: [], id: "page" });
  if (view === "services" && $("#service-pick").value !== state.formFor) buildForm();
  if (view === "graph") { renderGraph(); setTimeout(probeNodes, 500); }
  if (tabs[view] && ws && ws.readyState === 1) tabs[view].show();
  const hash = view === "topic" && $("#topic-pick").value ? `#topic=${$("#topic-pick").value}` : `#${view}`;
  if (location.hash !== hash) history.replaceState(null, "", hash);
}
document.querySelectorAll("nav button").forEach((b) => b.addEventListener("click", () => show(b.dataset.view)));

function renderGraph() {
  if (state.view !== "graph") return;
  const hide = $("#hide-rosout").checked ? new Set(["/rosout", "/rosout_agg"]) : new Set();
  drawGraph($("#graph"), state.pubs, state.subs, state.dead, (n) => send({ op: "x-mrosd.nodeDetails", node: n, id: n }), hide);
}
$("#hide-rosout").addEventListener("change", renderGraph);
let graphPending = false;
function renderGraphSoon() { if (!graphPending) { graphPending = true; setTimeout(() => { graphPending = false; renderGraph(); }, 300); } }
// While the graph shows, ask every node for its pid every 5 s: one that refuses is drawn dead (it died
// without unregistering; the master still lists it).
function probeNodes() {
  if (state.view !== "graph") return;
  const nodes = new Set();
  for (const m of [state.pubs, state.subs]) for (const ns of m.values()) for (const n of ns) nodes.add(n);
  for (const n of nodes) send({ op: "x-mrosd.nodeDetails", node: n, id: "probe" });
}
setInterval(probeNodes, 5000);

function showNode(m) {
  const list = (xs) => (xs && xs.length ? xs.map((x) => "  " + x).join("\n") : "  (none)");
  $("#node-info").textContent = `${m.node}\n${m.error ? "error: " + m.error + "\n" : ""}host: ${m.host ?? "?"}\npid: ${m.pid ?? "?"}`
    + `\nuri: ${m.uri ?? "?"}\n${m.alive === false ? "NOT ANSWERING\n" : ""}\nPublications:\n${list(m.publishing)}`
    + `\nSubscriptions:\n${list(m.subscribing)}\nServices:\n${list(m.services)}`;
  $("#node-info").className = "";
  renderGraph();
}

const fmtRate = (hz) => (hz == null ? "…" : hz >= 100 ? hz.toFixed(0) : hz.toFixed(1));
function fmtBytes(bps) {
  if (bps == null) return "…";
  const units = ["B/s", "KB/s", "MB/s", "GB/s"];
  let i = 0; while (bps >= 1000 && i < 3) { bps /= 1000; i++; }
  return `${bps.toFixed(bps >= 100 ? 0 : 1)} ${units[i]}`;
}
function renderTopics() {
  if (state.view !== "topics") return;
  const names = [...new Set([...state.byTopic.keys(), ...state.pubs.keys()])].sort();
  const rows = names.map((t) => {
    const s = state.stats.get(t) || {};
    const tr = document.createElement("tr");
    tr.dataset.topic = t;
    // The page's own measuring subscriber (the daemon's web node) is not one of the user's.
    const subs = [...(state.subs.get(t) || [])].filter((n) => n !== state.hubNode).length;
    for (const cell of [t, state.byTopic.get(t)?.schemaName ?? "?", (state.pubs.get(t) || new Set()).size,
      subs, fmtRate(s.hz), fmtBytes(s.bps)]) {
      const td = document.createElement("td"); td.textContent = cell; tr.append(td);
    }
    tr.children[4].dataset.hz = s.hz ?? "";
    const dropped = state.drops?.get(t);
    if (dropped) { tr.children[4].textContent += ` (${dropped} dropped here)`; tr.children[4].title = "dropped by the daemon for this page: the link is slower than the topic"; }
    tr.addEventListener("click", () => { $("#topic-pick").value = t; show("topic"); });
    return tr;
  });
  $("#topics tbody").replaceChildren(...rows);
}

function refreshTopicPick() {
  const pick = $("#topic-pick"), keep = pick.value || pendingTopic;
  pick.replaceChildren(...[...state.byTopic.keys()].sort().map((t) => new Option(t, t)));
  if (keep && state.byTopic.has(keep)) pick.value = keep;
  const shown = pick.value && imageSource(pick.value, state.byTopic.get(pick.value)?.schemaName).shown;
  if (state.view === "topic" && (!state.current || state.current.topic !== shown)) openTopic(pick.value);
}
$("#topic-pick").addEventListener("change", () => show("topic"));

function openTopic(topic) {
  unsubscribe(state.current); state.current = null;
  $("#tree").replaceChildren(); $("#topic-meta").textContent = "";
  if (!topic || !state.byTopic.has(topic)) return;
  const picked = state.byTopic.get(topic).schemaName;
  const { shown, type, mode } = imageSource(topic, picked);
  const isImage = type === "sensor_msgs/Image" || type === "sensor_msgs/CompressedImage";
  const isScan = type === "sensor_msgs/LaserScan" || type === "sensor_msgs/PointCloud2";
  $("#image").hidden = !isImage && !isScan;
  state.plotPath = null; plot.reset("");
  images.frames = 0; meter.reset();
  if (images.pending) { images.pending.resolve(false); images.pending = null; } // a frame of the last topic
  const cv = $("#image"); cv.getContext("2d").clearRect(0, 0, cv.width, cv.height);
  let latest = null, count = 0, t0 = performance.now();
  const rate = isImage ? imageChoice.rate.get(topic) ?? IMAGE_HZ : isScan ? IMAGE_HZ : TREE_HZ;
  state.current = subscribe(shown, (msg, t) => {
    latest = msg; count++;
    if (state.plotPath) plot.add(t, getPath(msg, state.plotPath));
    if (isImage) meter.arrived(t * 1e3);
    if (type === "sensor_msgs/Image") {
      try { images.drawRaw(msg); meter.drawn(msg.header?.stamp); } catch (e) { $("#topic-meta").textContent = e.message; }
    } else if (type === "sensor_msgs/CompressedImage") {
      images.drawCompressed(msg).then((drawn) => drawn && meter.drawn(msg.header?.stamp)).catch((e) => ($("#topic-meta").textContent = e.message));
    } else if (isScan) {
      try { (type === "sensor_msgs/LaserScan" ? drawScan : drawCloud)($("#image"), msg); images.frames++; }
      catch (e) { $("#topic-meta").textContent = e.message; }
    }
  }, rate);
  imageControls(topic, picked, mode, rate, isImage);
  const sub = state.current;
  const tick = () => {
    if (state.current !== sub) return;
    if (isImage) $("#image-overlay").textContent = meter.text(mode);
    if (latest) {
      if (!isImage || performance.now() - (sub.treeAt || 0) > 250) { renderTree(latest); sub.treeAt = performance.now(); }
      plot.draw();
      const dt = (performance.now() - t0) / 1000;
      if (dt >= 1) { $("#topic-meta").textContent = `${type} · ${(count / dt).toFixed(1)} shown/s`; count = 0; t0 = performance.now(); }
      latest = null;
    }
    setTimeout(tick, 1000 / TREE_HZ);
  };
  tick();
}

// --- image view: raw or T/compressed, its rate limit ----------------------------------------------
// A raw Image topic T with T/compressed advertised is shown from T/compressed by default when the link is
// slow (preferCompressed: the page not loaded over loopback), or as the user toggled it.
function imageSource(topic, type) {
  const twin = topic + "/compressed";
  if (type !== "sensor_msgs/Image" || !state.byTopic.has(twin)) return { shown: topic, type, mode: "" };
  const mode = imageChoice.mode.get(topic) ?? (preferCompressed() ? "compressed" : "raw");
  return mode === "compressed" ? { shown: twin, type: "sensor_msgs/CompressedImage", mode } : { shown: topic, type, mode };
}
function imageControls(topic, type, mode, rate, isImage) {
  $("#image-bar").hidden = !isImage;
  $("#image-overlay").hidden = !isImage;
  $("#image-mode").hidden = !mode;
  $("#image-mode").textContent = mode === "compressed" ? "compressed (JPEG) · show raw" : "raw · show compressed";
  $("#image-rate").value = String(rate);
  // a T/compressed made by mrosd answers with its settings (then shown); a real one is refused (stay hidden)
  $("#image-settings").hidden = true;
  if (mode === "compressed") send({ op: "x-mrosd.imageSettings", topic: topic + "/compressed" });
}
function showImageSettings(m) {
  if (m.topic !== $("#topic-pick").value + "/compressed") return;
  $("#image-settings").hidden = false;
  for (const [id, value] of [["#image-quality", m.quality], ["#image-width", m.maxWidth]]) {
    const pick = $(id);
    if (![...pick.options].some((o) => o.value === String(value))) pick.add(new Option(String(value), String(value)));
    pick.value = String(value);
  }
}
for (const [id, key] of [["#image-quality", "quality"], ["#image-width", "maxWidth"]]) {
  $(id).addEventListener("change", () => {
    send({ op: "x-mrosd.imageSettings", topic: $("#topic-pick").value + "/compressed", [key]: Number($(id).value) });
  });
}
$("#image-mode").addEventListener("click", () => {
  const topic = $("#topic-pick").value, type = state.byTopic.get(topic)?.schemaName;
  imageChoice.mode.set(topic, imageSource(topic, type).mode === "compressed" ? "raw" : "compressed");
  openTopic(topic);
});
$("#image-rate").addEventListener("change", () => {
  const topic = $("#topic-pick").value, hz = Math.max(0, Math.min(240, Number($("#image-rate").value) || 0));
  imageChoice.rate.set(topic, hz);
  if (state.current) send({ op: "x-mrosd.throttle", subscriptionId: state.current.id, maxRate: hz });
});

function getPath(msg, path) { let v = msg; for (const k of path) v = v?.[k]; return typeof v === "bigint" ? Number(v) : v; }

function renderTree(msg) {
  window.mrosdPage.treeUpdates++;
  const root = document.createElement("div");
  const build = (parent, value, path) => {
    const key = path.join(".");
    if (value !== null && typeof value === "object" && !("secs" in value && Object.keys(value).length === 2)) {
      const isTyped = ArrayBuffer.isView(value);
      const entries = Array.isArray(value) || isTyped ? [...Array(Math.min(value.length, MAX_ARRAY)).keys()].map((i) => [i, value[i]]) : Object.entries(value);
      const det = document.createElement("details");
      det.open = state.open.has(key) || (path.length < 2 && !(isTyped || Array.isArray(value)));
      det.addEventListener("toggle", () => (det.open ? state.open.add(key) : state.open.delete(key)));
      const sum = document.createElement("summary");
      sum.textContent = `${path.length ? path[path.length - 1] : "message"}${isTyped || Array.isArray(value) ? ` [${value.length}]` : ""}`;
      det.append(sum);
      if (det.open) for (const [k, v] of entries) build(det, v, [...path, k]);
      else det.addEventListener("toggle", () => renderTree(msg), { once: true });
      parent.append(det);
      return;
    }
    const leaf = document.createElement("div");
    leaf.className = "leaf";
    const shown = value && typeof value === "object" ? `${value.secs}.${String(value.nsecs).padStart(9, "0")}` : JSON.stringify(value);
    const span = document.createElement("span");
    span.textContent = shown;
    if (typeof value === "number") {
      span.className = "num" + (state.plotPath && state.plotPath.join(".") === key ? " plotted" : "");
      span.dataset.path = key;
      span.title = "plot this field";
      span.addEventListener("click", () => { state.plotPath = path; plot.reset(`${state.current.topic} ${key}`); renderTree(msg); });
    } else span.className = "str";
    leaf.append(`${path[path.length - 1]}: `, span);
    parent.append(leaf);
  };
  build(root, msg, []);
  $("#tree").replaceChildren(...root.childNodes);
}

function ensureRosout() {
  if (state.rosoutSub || !state.byTopic.has("/rosout")) return;
  state.rosoutSub = subscribe("/rosout", (m) => {
    state.log.push(m); if (state.log.length > MAX_LOG) state.log.shift();
    scheduleLog();
  });
}
let logPending = false;
function scheduleLog() { if (!logPending) { logPending = true; setTimeout(() => { logPending = false; renderLog(); }, 200); } }
// A log time as people read it: the local time of day to the millisecond (the date too when it is not today;
// a time before 2001, as simulated time starts near zero, as seconds); the exact stamp as its title.
function fmtStamp(secs, nsecs) {
  const exact = `${secs}.${String(nsecs).padStart(9, "0")}`;
  if (secs < 1e9) return [`${(secs + nsecs / 1e9).toFixed(3)} s`, exact];
  const d = new Date(secs * 1000 + Math.floor(nsecs / 1e6)), pad = (n, w = 2) => String(n).padStart(w, "0");
  const time = `${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}.${pad(d.getMilliseconds(), 3)}`;
  const day = `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())}`, now = new Date();
  const today = d.toDateString() === now.toDateString();
  return [today ? time : `${day} ${time}`, `${day} ${time} (${exact})`];
}
function renderLog() {
  const text = $("#log-filter").value.toLowerCase(), level = Number($("#log-level").value);
  const rows = state.log.filter((m) => m.level >= level && (!text || m.name.toLowerCase().includes(text) || m.msg.toLowerCase().includes(text)))
    .slice(-300).reverse().map((m) => {
      const tr = document.createElement("tr"); tr.className = "lvl-" + m.level;
      const name = { 1: "DEBUG", 2: "INFO", 4: "WARN", 8: "ERROR", 16: "FATAL" }[m.level] || m.level;
      const [when, exact] = fmtStamp(m.header.stamp.secs, m.header.stamp.nsecs);
      for (const c of [when, name, m.name, m.msg]) {
        const td = document.createElement("td"); td.textContent = c; tr.append(td);
      }
      tr.firstChild.title = exact;
      return tr;
    });
  $("#log tbody").replaceChildren(...rows);
}
$("#log-filter").addEventListener("input", renderLog);
$("#log-level").addEventListener("change", renderLog);

function renderParams(list) {
  const tree = {};
  for (const p of list) {
    const parts = p.name.split("/").filter(Boolean);
    let node = tree;
    parts.slice(0, -1).forEach((k) => (node = node[k + "/"] = node[k + "/"] || {}));
    node[parts[parts.length - 1]] = p.value;
  }
  const build = (obj, name) => {
    if (obj && typeof obj === "object" && !Array.isArray(obj)) {
      const det = document.createElement("details"); det.open = true;
      const s = document.createElement("summary"); s.textContent = name; det.append(s);
      for (const k of Object.keys(obj).sort()) det.append(build(obj[k], k));
      return det;
    }
    const d = document.createElement("div"); d.className = "leaf"; d.textContent = `${name}: ${JSON.stringify(obj)}`; return d;
  };
  $("#params").replaceChildren(build(tree, "/"));
}
$("#params-refresh").addEventListener("click", () => send({ op: "getParameters", parameterNames: [], id: "page" }));

// --- services: a form of the request's fields, the call as a Foxglove serviceCallRequest ---------------
const ENC = new TextEncoder().encode("ros1");
function refreshServices() {
  const pick = $("#service-pick"), keep = pick.value;
  const names = [...state.services.values()].map((sv) => sv.name).sort();
  pick.replaceChildren(...names.map((n) => new Option(n, n)));
  if (keep && names.includes(keep)) pick.value = keep;
  if (state.view === "services" && pick.value !== state.formFor) buildForm();
}
const serviceByName = (name) => [...state.services.values()].find((sv) => sv.name === name);
function buildForm() {
  const sv = serviceByName($("#service-pick").value);
  state.formFor = sv?.name;
  const form = $("#service-form");
  form.replaceChildren(); $("#service-response").replaceChildren(); $("#service-status").textContent = "";
  if (!sv) return;
  $("#service-type").textContent = sv.type;
  const def = parseDefinition(sv.type + "Request", sv.request?.schema ?? sv.requestSchema ?? "");
  const add = (type, path) => {
    const fields = def.types.get(type) || [];
    for (const f of fields) {
      const p = [...path, f.name];
      if (f.array === null && def.types.has(f.type)) { add(f.type, p); continue; }
      const label = document.createElement("label"); label.textContent = `${p.join(".")} (${f.type}${f.array === null ? "" : "[]"})`;
      const input = document.createElement("input");
      input.dataset.path = p.join("."); input.dataset.type = f.type; input.dataset.array = f.array === null ? "" : "1";
      const init = f.array === null ? defaultValue(def, f.type) : defaultValue(def, type)[f.name];
      if (f.type === "bool" && f.array === null) { input.type = "checkbox"; }
      else input.value = typeof init === "string" ? init : JSON.stringify(init);
      input.placeholder = f.array === null ? "" : "JSON array";
      label.htmlFor = input.id = "req-" + p.join("-");
      form.append(label, input);
    }
  };
  add(def.root, []);
  state.form = { sv, def };
}
$("#service-pick").addEventListener("change", buildForm);
$("#service-form").addEventListener("submit", (e) => { e.preventDefault(); callService(); });
$("#service-call").addEventListener("click", () => callService());

function callService() {
  if (!state.form) return;
  const { sv, def } = state.form;
  const request = defaultValue(def, def.root);
  try {
    for (const input of $("#service-form").querySelectorAll("input")) {
      const path = input.dataset.path.split("."), type = input.dataset.type;
      let value;
      if (input.dataset.array) value = JSON.parse(input.value || "[]");
      else if (type === "bool") value = input.checked;
      else if (type === "string") value = input.value;
      else if (type === "time" || type === "duration") value = JSON.parse(input.value);
      else { value = Number(input.value); if (!Number.isFinite(value)) throw new Error(`${input.dataset.path}: not a number`); }
      let obj = request;
      for (const k of path.slice(0, -1)) obj = obj[k];
      obj[path[path.length - 1]] = value;
    }
    const payload = serialize(def, request);
    const id = state.nextCall++;
    const frame = new Uint8Array(13 + ENC.length + payload.length), v = new DataView(frame.buffer);
    v.setUint8(0, 2); v.setUint32(1, sv.id, true); v.setUint32(5, id, true); v.setUint32(9, ENC.length, true);
    frame.set(ENC, 13); frame.set(payload, 13 + ENC.length);
    state.calls.set(id, { sv, t0: performance.now() });
    ws.send(frame);
    $("#service-status").textContent = "calling…";
  } catch (e) { $("#service-status").textContent = e.message; }
}

function onServiceResponse(v, buf) {
  const callId = v.getUint32(5, true), encLen = v.getUint32(9, true);
  if (tabCallDone(callId, new Uint8Array(buf, 13 + encLen))) return;
  const call = state.calls.get(callId);
  if (!call) return;
  state.calls.delete(callId);
  const sv = call.sv;
  try {
    const def = parseDefinition(sv.type + "Response", sv.response?.schema ?? sv.responseSchema ?? "");
    const resp = deserialize(def, new Uint8Array(buf, 13 + encLen));
    $("#service-status").textContent = `answered in ${(performance.now() - call.t0).toFixed(0)} ms`;
    const pre = document.createElement("pre"); pre.id = "service-result";
    pre.textContent = JSON.stringify(resp, (k, x) => (ArrayBuffer.isView(x) ? Array.from(x) : x), 2);
    $("#service-response").replaceChildren(pre);
  } catch (e) { $("#service-status").textContent = "response: " + e.message; }
}

// --- the TF, Actions, Reconfigure and Teleop tabs (tf.js, actions.js, reconfigure.js, teleop.js) ----------
// What they use of the connection: subscriptions, client channels (clientPublish) and service calls.
let nextChannel = 1;
const tabCalls = new Map();
const api = {
  state, subscribe, unsubscribe,
  advertise(topic, schemaName, schema) {
    const id = nextChannel++;
    send({ op: "advertise", channels: [{ id, topic, encoding: "ros1", schemaName, schema, schemaEncoding: "ros1msg" }] });
    return id;
  },
  unadvertise(id) { send({ op: "unadvertise", channelIds: [id] }); },
  publish(id, payload) {
    if (!ws || ws.readyState !== 1) return false;
    const frame = new Uint8Array(5 + payload.length);
    frame[0] = 1; new DataView(frame.buffer).setUint32(1, id, true); frame.set(payload, 5);
    ws.send(frame);
    return true;
  },
  // Call a service by name with a request object; resolves to the decoded response (10 s at most).
  callService(name, request) {
    const sv = serviceByName(name);
    if (!sv || !ws || ws.readyState !== 1) return Promise.reject(new Error(`${name} is not offered`));
    const req = parseDefinition(sv.type + "Request", sv.request?.schema ?? sv.requestSchema ?? "");
    const payload = serialize(req, request), id = state.nextCall++;
    const frame = new Uint8Array(13 + ENC.length + payload.length), v = new DataView(frame.buffer);
    v.setUint8(0, 2); v.setUint32(1, sv.id, true); v.setUint32(5, id, true); v.setUint32(9, ENC.length, true);
    frame.set(ENC, 13); frame.set(payload, 13 + ENC.length);
    return new Promise((resolve, reject) => {
      const timer = setTimeout(() => tabCallDone(id, null, "no answer in 10 s"), 10000);
      tabCalls.set(id, { sv, resolve, reject, timer });
      ws.send(frame);
    });
  },
};
function tabCallDone(id, body, error) {
  const call = tabCalls.get(id);
  if (!call) return false;
  tabCalls.delete(id); clearTimeout(call.timer);
  if (body === null) { call.reject(new Error(error)); return true; }
  try {
    const def = parseDefinition(call.sv.type + "Response", call.sv.response?.schema ?? call.sv.responseSchema ?? "");
    call.resolve(deserialize(def, body));
  } catch (e) { call.reject(e); }
  return true;
}
const tabs = {
  tf: new TfTab(api, $("#view-tf")), actions: new ActionsTab(api, $("#view-actions")),
  reconfigure: new ReconfigureTab(api, $("#view-reconfigure")), teleop: new TeleopTab(api, $("#view-teleop")),
};
window.mrosdPage.tabs = tabs;
function tabsChannels() { for (const t of Object.values(tabs)) if (t.channels) t.channels(); }
function tabsDisconnected() {
  for (const id of tabCalls.keys()) tabCallDone(id, null, "disconnected");
  for (const [name, t] of Object.entries(tabs)) { if (t.disconnected) t.disconnected(); if (name === state.view) t.hide(); }
}

// #topic=/name opens a topic, #topics the table, ... (bookmarkable, and how the tests open a view)
const VIEWS = ["graph", "topics", "topic", "log", "params", "services", "tf", "actions", "reconfigure", "teleop"];
const viewOfHash = () => {
  const topic = decodeURIComponent(location.hash.startsWith("#topic=") ? location.hash.slice(7) : "");
  const view = topic ? "topic" : location.hash.slice(1) || "graph";
  return [VIEWS.includes(view) ? view : "graph", topic];
};
let [firstView, pendingTopic] = viewOfHash();
state.view = firstView;
window.addEventListener("hashchange", () => {
  const [view, topic] = viewOfHash();
  if (topic) { pendingTopic = topic; if (state.byTopic.has(topic)) $("#topic-pick").value = topic; }
  if (view !== state.view || (topic && state.current?.topic !== topic)) show(view);
});
connect();
