// The Reconfigure tab: nodes offering dynamic_reconfigure (<node>/set_parameters and <node>/parameter_descriptions),
// their parameters as sliders (int/double with min and max), checkboxes (bool), selects (edit_method enums) and
// text fields (str), grouped as the description's groups are. A change calls <node>/set_parameters (a Foxglove
// service call) and shows the values the server answers with (it may adjust them); parameter_updates is followed.

// --- pure: a Python literal (edit_method is Python's repr of a dict), the description as plain data ---------
const MAX_LITERAL = 64 * 1024, MAX_NESTING = 32;

// Parse a Python literal (dict, list, tuple, str, int, float, True/False/None): no evaluation, bounded in size
// and nesting; throws on anything else.
export function parsePyLiteral(text) {
  if (typeof text !== "string" || text.length > MAX_LITERAL) throw new Error("literal too long");
  let i = 0;
  const ws = () => { while (i < text.length && /\s/.test(text[i])) i++; };
  const fail = (what) => { throw new Error(`${what} at ${i}`); };
  const value = (depth) => {
    if (depth > MAX_NESTING) fail("nested too deep");
    ws();
    const ch = text[i];
    if (ch === "{" || ch === "[" || ch === "(") {
      const close = { "{": "}", "[": "]", "(": ")" }[ch];
      i++;
      const dict = ch === "{", out = dict ? {} : [];
      for (;;) {
        ws();
        if (text[i] === close) { i++; return out; }
        const k = value(depth + 1);
        if (dict) {
          ws(); if (text[i] !== ":") fail("':' expected");
          i++;
          const v = value(depth + 1);
          if (typeof k !== "string" && typeof k !== "number") fail("a key must be a string or number");
          Object.defineProperty(out, String(k), { value: v, enumerable: true, writable: true, configurable: true });
        } else out.push(k);
        ws();
        if (text[i] === ",") { i++; continue; }
        if (text[i] !== close) fail(`'${close}' expected`);
      }
    }
    if (ch === "'" || ch === '"') {
      i++;
      let s = "";
      while (i < text.length && text[i] !== ch) {
        if (text[i] === "\\") {
          const e = text[++i];
          const simple = { n: "\n", t: "\t", r: "\r", "\\": "\\", "'": "'", '"': '"', 0: "\0" }[e];
          if (simple !== undefined) { s += simple; i++; continue; }
          if (e === "x" || e === "u") {
            const n = e === "x" ? 2 : 4, hex = text.slice(i + 1, i + 1 + n);
            if (!/^[0-9a-fA-F]+$/.test(hex) || hex.length !== n) fail("bad escape");
            s += String.fromCharCode(parseInt(hex, 16)); i += 1 + n; continue;
          }
          s += "\\"; continue;
        }
        s += text[i++];
      }
      if (text[i] !== ch) fail("unterminated string");
      i++;
      return s;
    }
    const word = /^(True|False|None|[-+]?(?:\d+\.?\d*(?:[eE][-+]?\d+)?|\.\d+(?:[eE][-+]?\d+)?|inf|nan))/.exec(text.slice(i, i + 64));
    if (!word) fail("unexpected input");
    i += word[0].length;
    const w = word[0];
    if (w === "True") return true;
    if (w === "False") return false;
    if (w === "None") return null;
    return Number(w.replace(/inf$/, "Infinity").replace(/nan$/, "NaN"));
  };
  const v = value(0);
  ws();
  if (i !== text.length) fail("trailing input");
  return v;
}

const KINDS = [["bools", "bool"], ["ints", "int"], ["strs", "str"], ["doubles", "double"]];

// A Config message as Map(name -> value).
export function configValues(config) {
  const out = new Map();
  for (const [field] of KINDS) for (const p of config?.[field] || []) out.set(p.name, p.value);
  return out;
}

// A Config message setting `changes` ([{name, type, value}]).
export function configOf(changes) {
  const config = { bools: [], ints: [], strs: [], doubles: [], groups: [] };
  for (const c of changes) {
    const field = KINDS.find(([, t]) => t === c.type)?.[0];
    if (field) config[field].push({ name: c.name, value: c.value });
  }
  return config;
}

// A ConfigDescription as groups [{name, id, parent, params: [{name, type, level, description, min, max, dflt,
// enum: [{name, value, description}] | null}]}] in the description's order; an edit_method that does not parse
// leaves the parameter without an enum.
export function describe(desc) {
  const min = configValues(desc.min), max = configValues(desc.max), dflt = configValues(desc.dflt);
  return (desc.groups || []).map((g) => ({
    name: g.name, id: g.id, parent: g.parent, type: g.type,
    params: (g.parameters || []).map((p) => {
      let en = null;
      if (p.edit_method) {
        try {
          const m = parsePyLiteral(p.edit_method);
          if (m && Array.isArray(m.enum)) en = m.enum.filter((c) => c && typeof c.name === "string").map((c) => ({ name: c.name, value: c.value, description: typeof c.description === "string" ? c.description : "" }));
        } catch { en = null; }
      }
      return { name: p.name, type: p.type, level: p.level, description: p.description, min: min.get(p.name), max: max.get(p.name), dflt: dflt.get(p.name), enum: en };
    }),
  }));
}

// The number a slider's position stands for (ints rounded), and a slider's step.
export const sliderStep = (p) => (p.type === "int" ? 1 : (p.max - p.min) / 1000);
export const sliderValue = (p, raw) => (p.type === "int" ? Math.round(Number(raw)) : Number(raw));
// A slider only for a finite range that is not dynamic_reconfigure's "unbounded" (INT_MAX, DBL_MAX, inf).
export const hasRange = (p) => (p.type === "int" || p.type === "double") && Number.isFinite(p.min) && Number.isFinite(p.max)
  && p.max > p.min && Math.abs(p.min) < 2147483647 && Math.abs(p.max) < 2147483647;

// --- the tab --------------------------------------------------------------------------------------------
const el = (tag, props = {}, ...kids) => { const e = Object.assign(document.createElement(tag), props); e.append(...kids); return e; };
const fmt = (v) => (typeof v === "number" && !Number.isInteger(v) ? String(Number(v.toPrecision(6))) : String(v));

export class ReconfigureTab {
  constructor(api, root) {
    this.api = api; this.on = false; this.node = null; this.subs = []; this.controls = new Map(); this.params = new Map();
    this.pick = el("select", { id: "reconf-pick" });
    this.statusEl = el("span", { id: "reconf-status", className: "hint" });
    this.body = el("div", { id: "reconf-groups" });
    root.append(el("div", { className: "bar" }, this.pick, this.statusEl), this.body);
    this.pick.addEventListener("change", () => this.open(this.pick.value));
  }
  show() { this.on = true; this.channels(); }
  hide() { this.on = false; this.close(); }
  nodes() {
    const topics = this.api.state.byTopic, out = [];
    for (const sv of this.api.state.services.values()) {
      if (sv.type !== "dynamic_reconfigure/Reconfigure" || !sv.name.endsWith("/set_parameters")) continue;
      const node = sv.name.slice(0, -"/set_parameters".length);
      if (topics.has(node + "/parameter_descriptions")) out.push(node);
    }
    return out.sort();
  }
  channels() {
    if (!this.on) return;
    const names = this.nodes(), keep = this.pick.value;
    if ([...this.pick.options].map((o) => o.value).join("\n") !== names.join("\n")) {
      this.pick.replaceChildren(...names.map((n) => new Option(n, n)));
      if (names.includes(keep)) this.pick.value = keep;
    }
    if (this.pick.value !== (this.node ?? "")) this.open(this.pick.value);
  }
  close() {
    for (const s of this.subs) this.api.unsubscribe(s);
    this.subs = []; this.node = null; this.controls.clear(); this.params.clear();
    this.body.replaceChildren();
  }
  open(node) {
    this.close();
    if (!node) return;
    this.node = node; this.statusEl.textContent = "waiting for the description…";
    this.subs = [
      this.api.subscribe(node + "/parameter_descriptions", (m) => this.build(m)),
      this.api.subscribe(node + "/parameter_updates", (m) => this.values(m, "update")),
    ].filter(Boolean);
  }
  build(desc) {
    const groups = describe(desc);
    this.controls.clear(); this.params.clear();
    const boxes = new Map(), top = [];
    for (const g of groups) {
      const box = el("fieldset", { className: "reconf-group" }, el("legend", {}, g.name));
      box.dataset.group = g.name;
      const grid = el("div", { className: "form" });
      box.append(grid);
      for (const p of g.params) { this.params.set(p.name, p); grid.append(...this.control(p)); }
      boxes.set(g.id, box);
    }
    for (const g of groups) { // a group inside its parent's box (the root group is its own parent)
      const box = boxes.get(g.id), parent = g.id !== g.parent ? boxes.get(g.parent) : null;
      if (parent && parent !== box && !box.contains(parent)) parent.append(box); else if (!top.includes(box)) top.push(box);
    }
    this.body.replaceChildren(...top);
    this.statusEl.textContent = "";
    if (this.last) this.values(this.last, "update");
  }
  control(p) {
    const id = "reconf-" + p.name;
    const label = el("label", { htmlFor: id, title: p.description || "" }, p.name);
    let input, shown = null;
    if (p.enum && p.enum.length) {
      input = el("select", { id });
      input.append(...p.enum.map((c) => { const o = new Option(`${c.name} (${c.value})`, String(c.value)); o.title = c.description; return o; }));
      input.addEventListener("change", () => this.set(p, p.type === "str" ? input.value : Number(input.value)));
    } else if (p.type === "bool") {
      input = el("input", { id, type: "checkbox" });
      input.addEventListener("change", () => this.set(p, input.checked));
    } else if (hasRange(p)) {
      input = el("input", { id, type: "range", min: p.min, max: p.max, step: sliderStep(p) });
      shown = el("output", { htmlFor: id, className: "hint" });
      input.addEventListener("input", () => { shown.textContent = fmt(sliderValue(p, input.value)); });
      input.addEventListener("change", () => this.set(p, sliderValue(p, input.value)));
    } else {
      input = el("input", { id, type: p.type === "str" ? "text" : "number" });
      if (p.type === "double") input.step = "any";
      input.addEventListener("change", () => this.set(p, p.type === "str" ? input.value : Number(input.value)));
    }
    input.dataset.param = p.name;
    this.controls.set(p.name, { input, shown, p });
    const cell = el("span", { className: "reconf-value" }, input);
    if (shown) cell.append(" ", shown);
    return [label, cell];
  }
  // Show a Config (parameter_updates, or the service's answer).
  values(config, from) {
    this.last = config;
    for (const [name, value] of configValues(config)) {
      const c = this.controls.get(name);
      if (!c || (from === "update" && document.activeElement === c.input && c.input.type !== "range" && c.input.type !== "checkbox")) continue;
      if (c.input.type === "checkbox") c.input.checked = Boolean(value);
      else c.input.value = String(value);
      if (c.shown) c.shown.textContent = fmt(value);
      c.input.dataset.value = String(value);
    }
  }
  async set(p, value) {
    const node = this.node;
    if (p.type !== "str" && p.type !== "bool" && !Number.isFinite(value)) { this.statusEl.textContent = `${p.name}: not a number`; return; }
    this.statusEl.textContent = `setting ${p.name} = ${fmt(value)}…`;
    try {
      const resp = await this.api.callService(node + "/set_parameters", { config: configOf([{ name: p.name, type: p.type, value }]) });
      if (this.node !== node) return;
      this.values(resp.config, "answer");
      const got = configValues(resp.config).get(p.name);
      this.statusEl.textContent = got === value ? `${p.name} = ${fmt(got)}` : `${p.name}: asked ${fmt(value)}, the server set ${fmt(got)}`;
      this.statusEl.dataset.answered = `${p.name}=${got}`;
    } catch (e) { this.statusEl.textContent = `${p.name}: ${e.message}`; }
  }
}
