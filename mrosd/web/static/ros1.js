// ROS 1 messages in the browser: parse a TCPROS message_definition, read a serialized body with DataView.
// The server forwards raw TCPROS bodies and advertises each topic's full definition; this is all the page
// needs to show any type, including ones mrosd never heard of.

const PRIMITIVE = {
  bool: [1, (v, o) => v.getUint8(o) !== 0],
  int8: [1, (v, o) => v.getInt8(o)],
  uint8: [1, (v, o) => v.getUint8(o)],
  byte: [1, (v, o) => v.getUint8(o)],
  char: [1, (v, o) => v.getUint8(o)],
  int16: [2, (v, o) => v.getInt16(o, true)],
  uint16: [2, (v, o) => v.getUint16(o, true)],
  int32: [4, (v, o) => v.getInt32(o, true)],
  uint32: [4, (v, o) => v.getUint32(o, true)],
  int64: [8, (v, o) => Number(v.getBigInt64(o, true))],
  uint64: [8, (v, o) => Number(v.getBigUint64(o, true))],
  float32: [4, (v, o) => v.getFloat32(o, true)],
  float64: [8, (v, o) => v.getFloat64(o, true)],
};
const TYPED = { int8: Int8Array, int16: Int16Array, uint16: Uint16Array, int32: Int32Array,
  uint32: Uint32Array, float32: Float32Array, float64: Float64Array };
const decoder = new TextDecoder();

export class DecodeError extends Error {
  constructor(message) { super(message); this.name = "DecodeError"; }
}

// Parse a definition into {root, types: Map(fullName -> [{name, type, array: null|-1|N}])}.
export function parseDefinition(rootType, text) {
  const sections = text.split(/^={10,}\s*$/m);
  const types = new Map();
  const order = [];
  sections.forEach((section, i) => {
    let name = rootType;
    const lines = section.split("\n");
    if (i > 0) {
      const head = lines.findIndex((l) => l.trim().startsWith("MSG:"));
      if (head < 0) return;
      name = lines[head].trim().slice(4).trim();
      lines.splice(0, head + 1);
    }
    const fields = [];
    for (const raw of lines) {
      const line = raw.replace(/#.*$/, "").trim();
      if (!line) continue;
      const m = /^([\w/]+)(\[(\d*)\])?\s+(\w+)\s*(=.*)?$/.exec(line);
      if (!m) continue;
      if (m[5] !== undefined || /^\S+\s+\w+\s*=/.test(raw)) continue; // a constant
      fields.push({ type: m[1], array: m[2] === undefined ? null : m[3] === "" ? -1 : Number(m[3]), name: m[4] });
    }
    types.set(name, fields);
    order.push(name);
  });
  const pkgOf = (t) => (t.includes("/") ? t.split("/")[0] : "");
  for (const [name, fields] of types) {
    for (const f of fields) {
      if (f.type in PRIMITIVE || f.type === "string" || f.type === "time" || f.type === "duration") continue;
      if (f.type === "Header") { f.type = "std_msgs/Header"; continue; }
      if (f.type.includes("/")) continue;
      const same = `${pkgOf(name)}/${f.type}`;
      f.type = types.has(same) ? same : order.find((t) => t.endsWith("/" + f.type)) || same;
    }
  }
  return { root: rootType, types };
}

// Deserialize a body (ArrayBuffer/Uint8Array) of the root type; uint8/int8/float arrays come back typed.
export function deserialize(def, bytes) {
  const u8 = bytes instanceof Uint8Array ? bytes : new Uint8Array(bytes);
  const view = new DataView(u8.buffer, u8.byteOffset, u8.byteLength);
  const state = { o: 0 };
  const need = (n) => { if (state.o + n > u8.byteLength) throw new DecodeError(`truncated at byte ${state.o}`); };
  const readOne = (type) => {
    const p = PRIMITIVE[type];
    if (p) { need(p[0]); const v = p[1](view, state.o); state.o += p[0]; return v; }
    if (type === "string") {
      need(4); const n = view.getUint32(state.o, true); state.o += 4; need(n);
      const s = decoder.decode(u8.subarray(state.o, state.o + n)); state.o += n; return s;
    }
    if (type === "time" || type === "duration") {
      need(8); const secs = type === "time" ? view.getUint32(state.o, true) : view.getInt32(state.o, true);
      const nsecs = view.getUint32(state.o + 4, true); state.o += 8; return { secs, nsecs };
    }
    const fields = def.types.get(type);
    if (!fields) throw new DecodeError(`no definition of ${type}`);
    const out = {};
    for (const f of fields) out[f.name] = f.array === null ? readOne(f.type) : readArray(f);
    return out;
  };
  const readArray = (f) => {
    let n = f.array;
    if (n < 0) { need(4); n = view.getUint32(state.o, true); state.o += 4; }
    if (f.type === "uint8" || f.type === "char" || f.type === "byte") {
      need(n); const a = u8.subarray(state.o, state.o + n); state.o += n; return a;
    }
    const T = TYPED[f.type];
    if (T) {
      need(n * T.BYTES_PER_ELEMENT);
      const a = new T(n);
      const p = PRIMITIVE[f.type];
      for (let i = 0; i < n; i++) a[i] = p[1](view, state.o + i * T.BYTES_PER_ELEMENT);
      state.o += n * T.BYTES_PER_ELEMENT; return a;
    }
    if (n > u8.byteLength - state.o) throw new DecodeError(`array of ${n} beyond the body`);
    const a = new Array(n);
    for (let i = 0; i < n; i++) a[i] = readOne(f.type);
    return a;
  };
  return readOne(def.root);
}

const WRITE = {
  bool: [1, (v, o, x) => v.setUint8(o, x ? 1 : 0)], int8: [1, (v, o, x) => v.setInt8(o, x)],
  uint8: [1, (v, o, x) => v.setUint8(o, x)], byte: [1, (v, o, x) => v.setUint8(o, x)], char: [1, (v, o, x) => v.setUint8(o, x)],
  int16: [2, (v, o, x) => v.setInt16(o, x, true)], uint16: [2, (v, o, x) => v.setUint16(o, x, true)],
  int32: [4, (v, o, x) => v.setInt32(o, x, true)], uint32: [4, (v, o, x) => v.setUint32(o, x, true)],
  int64: [8, (v, o, x) => v.setBigInt64(o, BigInt(Math.trunc(x)), true)],
  uint64: [8, (v, o, x) => v.setBigUint64(o, BigInt(Math.trunc(x)), true)],
  float32: [4, (v, o, x) => v.setFloat32(o, x, true)], float64: [8, (v, o, x) => v.setFloat64(o, x, true)],
};

// The default value of a type (what a form starts from): zeros, empty strings and arrays.
export function defaultValue(def, type) {
  if (type in WRITE) return type === "bool" ? false : 0;
  if (type === "string") return "";
  if (type === "time" || type === "duration") return { secs: 0, nsecs: 0 };
  const out = {};
  for (const f of def.types.get(type) || []) {
    out[f.name] = f.array === null ? defaultValue(def, f.type) : Array.from({ length: Math.max(f.array, 0) }, () => defaultValue(def, f.type));
  }
  return out;
}

// Serialize `value` as the root type of `def` (the inverse of deserialize; missing fields are defaults).
export function serialize(def, value) {
  let buf = new Uint8Array(256), view = new DataView(buf.buffer), o = 0;
  const room = (n) => {
    if (o + n <= buf.length) return;
    const bigger = new Uint8Array(Math.max(buf.length * 2, o + n));
    bigger.set(buf); buf = bigger; view = new DataView(buf.buffer);
  };
  const encoder = new TextEncoder();
  const writeOne = (type, x) => {
    const w = WRITE[type];
    if (w) { room(w[0]); w[1](view, o, x ?? 0); o += w[0]; return; }
    if (type === "string") {
      const b = encoder.encode(String(x ?? "")); room(4 + b.length);
      view.setUint32(o, b.length, true); buf.set(b, o + 4); o += 4 + b.length; return;
    }
    if (type === "time" || type === "duration") {
      room(8); const t = x || {};
      if (type === "time") view.setUint32(o, t.secs || 0, true); else view.setInt32(o, t.secs || 0, true);
      view.setUint32(o + 4, t.nsecs || 0, true); o += 8; return;
    }
    const fields = def.types.get(type);
    if (!fields) throw new DecodeError(`no definition of ${type}`);
    const obj = x || {};
    for (const f of fields) {
      const v = obj[f.name];
      if (f.array === null) { writeOne(f.type, v ?? defaultValue(def, f.type)); continue; }
      const items = Array.from(v ?? []);
      if (f.array >= 0 && items.length !== f.array) throw new DecodeError(`${f.name}: ${f.array} items expected, got ${items.length}`);
      if (f.array < 0) { room(4); view.setUint32(o, items.length, true); o += 4; }
      for (const item of items) writeOne(f.type, item);
    }
  };
  writeOne(def.root, value);
  return buf.slice(0, o);
}
