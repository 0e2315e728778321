// The Actions tab: running actionlib servers (X/goal, X/cancel, X/status, X/feedback, X/result), a goal form
// built from the goal type's definition (the ...ActionGoal's `goal` field), the goal sent on X/goal with
// actionlib's goal id and stamps, its status and feedback live, its result, and a cancel button (X/cancel).
import { parseDefinition, serialize, defaultValue } from "./ros1.js";

export const STATUS = ["PENDING", "ACTIVE", "PREEMPTED", "SUCCEEDED", "ABORTED", "REJECTED", "PREEMPTING", "RECALLING", "RECALLED", "LOST"];
const TERMINAL = new Set([2, 3, 4, 5, 8, 9]);
const GOAL_ID_DEF = "time stamp\nstring id\n";

// The action servers among the advertised channels ([{topic, schemaName, schema}]): X with an X/goal of an
// ...ActionGoal type and an X/status; sorted by name.
export function actionServers(channels) {
  const by = new Map(channels.map((c) => [c.topic, c]));
  const out = [];
  for (const c of channels) {
    if (!c.topic.endsWith("/goal") || !/ActionGoal$/.test(c.schemaName)) continue;
    const name = c.topic.slice(0, -5);
    const status = by.get(name + "/status");
    if (!status || status.schemaName !== "actionlib_msgs/GoalStatusArray") continue;
    out.push({ name, type: c.schemaName.slice(0, -4), goal: c, cancel: by.get(name + "/cancel"), status, feedback: by.get(name + "/feedback"), result: by.get(name + "/result") });
  }
  return out.sort((a, b) => (a.name < b.name ? -1 : a.name > b.name ? 1 : 0));
}

// actionlib's GoalIDGenerator: "<node name>-<count>-<now in s with 3 decimals>".
export const goalId = (node, count, nowSec) => `${node}-${count}-${nowSec.toFixed(3)}`;
export const stampOf = (ms) => ({ secs: Math.floor(ms / 1000), nsecs: Math.round((ms % 1000) * 1e6) % 1e9 });

// The leaf fields of `type` as form inputs: [{path: [names], type, array: null|-1|N}] (nested messages flattened,
// arrays of anything one JSON field).
export function leafFields(def, type, path = [], depth = 0) {
  const out = [];
  if (depth > 32) return out;
  for (const f of def.types.get(type) || []) {
    const p = [...path, f.name];
    if (f.array === null && def.types.has(f.type)) out.push(...leafFields(def, f.type, p, depth + 1));
    else out.push({ path: p, type: f.type, array: f.array });
  }
  return out;
}

// The value of one input as the field's type wants it (throws with the field's name when it is not one).
export function fieldValue(field, text, checked) {
  const name = field.path.join(".");
  if (field.array !== null) {
    const v = JSON.parse(text || "[]");
    if (!Array.isArray(v)) throw new Error(`${name}: a JSON array expected`);
    return v;
  }
  if (field.type === "bool") return Boolean(checked);
  if (field.type === "string") return text;
  if (field.type === "time" || field.type === "duration") return JSON.parse(text);
  const v = Number(text);
  if (text.trim() === "" || !Number.isFinite(v)) throw new Error(`${name}: not a number`);
  if (!/float/.test(field.type) && !Number.isInteger(v)) throw new Error(`${name}: not an integer`);
  return v;
}

export function setPath(obj, path, value) {
  let o = obj;
  for (const k of path.slice(0, -1)) o = o[k];
  o[path[path.length - 1]] = value;
}

// The ActionGoal message for `goal` (the Goal's value), as actionlib's client makes it: the goal id's stamp and
// the header's stamp are the send time.
export function actionGoal(id, goal, ms) {
  const stamp = stampOf(ms);
  return { header: { seq: 0, stamp, frame_id: "" }, goal_id: { stamp, id }, goal };
}

const el = (tag, props = {}, ...kids) => { const e = Object.assign(document.createElement(tag), props); e.append(...kids); return e; };
const RETRY_MS = 400, RETRY_FOR_MS = 5000;
const json = (v) => JSON.stringify(v, (k, x) => (ArrayBuffer.isView(x) ? Array.from(x) : x), 2);

export class ActionsTab {
  constructor(api, root) {
    this.api = api; this.count = 0; this.on = false;
    this.tag = Math.random().toString(36).slice(2, 8);
    this.pick = el("select", { id: "action-pick" });
    this.typeLabel = el("span", { className: "hint", id: "action-type" });
    this.form = el("form", { id: "action-form", className: "form" });
    this.sendBtn = el("button", { id: "action-send", type: "button" }, "Send goal");
    this.cancelBtn = el("button", { id: "action-cancel", type: "button", disabled: true }, "Cancel");
    this.statusEl = el("span", { id: "action-status", className: "hint" });
    this.feedbackEl = el("pre", { id: "action-feedback", className: "tree" });
    this.resultEl = el("pre", { id: "action-result", className: "tree" });
    root.append(
      el("div", { className: "bar" }, this.pick, this.typeLabel),
      this.form,
      el("div", { className: "bar" }, this.sendBtn, this.cancelBtn, this.statusEl),
      el("div", { className: "hint" }, "feedback"), this.feedbackEl,
      el("div", { className: "hint" }, "result"), this.resultEl,
    );
    this.pick.addEventListener("change", () => this.open(this.pick.value));
    this.form.addEventListener("submit", (e) => { e.preventDefault(); this.sendGoal(); });
    this.sendBtn.addEventListener("click", () => this.sendGoal());
    this.cancelBtn.addEventListener("click", () => this.cancelGoal());
    this.server = null; this.subs = []; this.pubs = null; this.goal = null;
  }
  show() { this.on = true; this.channels(); }
  hide() { this.on = false; this.close(); }
  channels() {
    if (!this.on) return;
    const servers = actionServers([...this.api.state.byTopic.values()]);
    this.servers = new Map(servers.map((s) => [s.name, s]));
    const keep = this.pick.value;
    const names = servers.map((s) => s.name);
    if ([...this.pick.options].map((o) => o.value).join("\n") !== names.join("\n")) {
      this.pick.replaceChildren(...names.map((n) => new Option(n, n)));
      if (names.includes(keep)) this.pick.value = keep;
    }
    if (this.pick.value !== (this.server?.name ?? "")) this.open(this.pick.value);
  }
  close() {
    for (const s of this.subs) this.api.unsubscribe(s);
    if (this.pubs) { this.api.unadvertise(this.pubs.goal); this.api.unadvertise(this.pubs.cancel); }
    this.subs = []; this.pubs = null; this.server = null;
    clearTimeout(this.retry);
  }
  open(name) {
    this.close();
    this.form.replaceChildren(); this.typeLabel.textContent = "";
    const sv = this.servers?.get(name);
    if (!sv) return;
    this.server = sv;
    this.typeLabel.textContent = sv.type;
    const def = parseDefinition(sv.goal.schemaName, sv.goal.schema);
    const goalType = (def.types.get(def.root) || []).find((f) => f.name === "goal")?.type;
    this.def = def; this.goalType = goalType;
    this.fields = goalType ? leafFields(def, goalType) : [];
    for (const f of this.fields) {
      const id = "goal-" + f.path.join("-");
      const input = el("input", { id });
      input.dataset.path = f.path.join(".");
      if (f.type === "bool" && f.array === null) input.type = "checkbox";
      else {
        const init = f.array === null ? defaultValue(def, f.type) : [];
        input.value = typeof init === "string" ? init : JSON.stringify(init);
      }
      if (f.array !== null) input.placeholder = "JSON array";
      this.form.append(el("label", { htmlFor: id }, `${f.path.join(".")} (${f.type}${f.array === null ? "" : "[]"})`), input);
    }
    this.pubs = {
      goal: this.api.advertise(sv.goal.topic, sv.goal.schemaName, sv.goal.schema),
      cancel: this.api.advertise(sv.name + "/cancel", "actionlib_msgs/GoalID", sv.cancel?.schema ?? GOAL_ID_DEF),
    };
    this.cancelDef = parseDefinition("actionlib_msgs/GoalID", sv.cancel?.schema ?? GOAL_ID_DEF);
    this.subs = [
      this.api.subscribe(sv.status.topic, (m) => this.onStatus(m)),
      sv.feedback && this.api.subscribe(sv.feedback.topic, (m) => this.onFeedback(m), 20),
      sv.result && this.api.subscribe(sv.result.topic, (m) => this.onResult(m)),
    ].filter(Boolean);
  }
  setStatus(code, text) {
    const name = STATUS[code] ?? String(code);
    this.statusEl.textContent = `${this.goal?.id ?? ""}: ${name}${text ? " (" + text + ")" : ""}`;
    this.statusEl.dataset.status = name;
    if (this.goal) this.goal.status = code;
    this.cancelBtn.disabled = !this.goal || TERMINAL.has(code);
  }
  sendGoal() {
    if (!this.server || !this.pubs) return;
    try {
      const goal = defaultValue(this.def, this.goalType);
      for (const f of this.fields) {
        const input = this.form.querySelector(`[id="goal-${CSS.escape(f.path.join("-"))}"]`);
        setPath(goal, f.path, fieldValue(f, input.value, input.checked));
      }
      const now = Date.now();
      const id = goalId(`${this.api.state.hubNode}/page_${this.tag}`, ++this.count, now / 1000);
      const bytes = serialize(this.def, actionGoal(id, goal, now));
      this.goal = { id, status: null, seen: false, sent: now, bytes, cancelled: null };
      this.feedbackEl.textContent = ""; this.resultEl.textContent = "";
      this.setStatus("sent", "");
      this.statusEl.dataset.status = "SENT";
      this.api.publish(this.pubs.goal, bytes);
      this.scheduleRetry();
    } catch (e) { this.statusEl.textContent = e.message; this.statusEl.dataset.status = "ERROR"; }
  }
  // The server subscribes to the page's new X/goal publisher after it is advertised: a goal sent before that
  // connection is lost, so it is sent again (same id: actionlib ignores a goal id it has) until the server
  // lists it; a cancel likewise until the goal ends. Bounded to RETRY_FOR_MS.
  scheduleRetry() {
    clearTimeout(this.retry);
    this.retry = setTimeout(() => {
      const g = this.goal;
      if (!g || !this.pubs || Date.now() - (g.cancelled ?? g.sent) > RETRY_FOR_MS) return;
      if (!g.seen) this.api.publish(this.pubs.goal, g.bytes);
      else if (g.cancelled !== null && !TERMINAL.has(g.status)) this.api.publish(this.pubs.cancel, g.cancelBytes);
      else return;
      this.scheduleRetry();
    }, RETRY_MS);
  }
  cancelGoal() {
    const g = this.goal;
    if (!g || !this.pubs) return;
    g.cancelBytes = serialize(this.cancelDef, { stamp: { secs: 0, nsecs: 0 }, id: g.id });
    g.cancelled = Date.now();
    this.api.publish(this.pubs.cancel, g.cancelBytes);
    this.scheduleRetry();
  }
  mine(goalIdMsg) { return this.goal && goalIdMsg.id === this.goal.id; }
  onStatus(m) {
    const s = m.status_list.find((x) => this.mine(x.goal_id));
    if (!s) return;
    this.goal.seen = true;
    if (this.goal.status === null || !TERMINAL.has(this.goal.status)) this.setStatus(s.status, s.text);
  }
  onFeedback(m) {
    if (!this.mine(m.status.goal_id)) return;
    this.goal.seen = true;
    this.feedbackEl.textContent = json(m.feedback);
    if (!TERMINAL.has(this.goal.status)) this.setStatus(m.status.status, m.status.text);
  }
  onResult(m) {
    if (!this.mine(m.status.goal_id)) return;
    this.goal.seen = true;
    this.resultEl.textContent = json(m.result);
    this.setStatus(m.status.status, m.status.text);
  }
}
