// The drive tabs' pure parts under node (tests/web/test_web_page_drive_units.py): the input is a JSON object of
// cases from Python (bodies serialized by mrosd, base64); the output is what the page's modules make of them.
import { readFileSync } from "node:fs";
import { parseDefinition, deserialize, serialize } from "../../mrosd/web/static/ros1.js";
import { compose, invert, apply, lookup, toRoot, treeRows, frameId, FrameStore, yaw } from "../../mrosd/web/static/tf.js";
import { actionServers, goalId, stampOf, leafFields, fieldValue, actionGoal, setPath } from "../../mrosd/web/static/actions.js";
import { parsePyLiteral, describe, configOf, configValues, hasRange } from "../../mrosd/web/static/reconfigure.js";
import { twistOf, keysStick, limitOf, TWIST_DEF } from "../../mrosd/web/static/teleop.js";

const input = JSON.parse(readFileSync(0, "utf8"));
const b64 = (u8) => Buffer.from(u8).toString("base64");
const tryOr = (f) => { try { return { value: f() }; } catch (e) { return { error: e.message }; } };
const plain = (v) => JSON.parse(JSON.stringify(v, (k, x) => (ArrayBuffer.isView(x) ? Array.from(x) : x === Infinity ? "inf" : x === -Infinity ? "-inf" : x)));
const out = {};

// --- TF -------------------------------------------------------------------------------------------------
const q = (yawRad) => [0, 0, Math.sin(yawRad / 2), Math.cos(yawRad / 2)];
const frames = new Map([
  ["base", { parent: "world", T: { t: [1, 2, 0], q: q(Math.PI / 2) } }],
  ["laser", { parent: "base", T: { t: [0.5, 0, 0.2], q: q(0) } }],
  ["cam", { parent: "base", T: { t: [0, 0.3, 1], q: [Math.sin(0.4), 0, 0, Math.cos(0.4)] } }],
  ["island", { parent: "sea", T: { t: [9, 9, 9], q: q(0) } }],
  ["a", { parent: "b", T: { t: [1, 0, 0], q: q(0) } }], ["b", { parent: "a", T: { t: [1, 0, 0], q: q(0) } }],
]);
const T = lookup(frames, "world", "laser");
const back = lookup(frames, "laser", "world");
const rt = compose(T, back);
const camInLaser = lookup(frames, "laser", "cam");
out.tf = {
  laserInWorld: T.t, laserYaw: yaw(T.q), roundTrip: [...rt.t, ...rt.q],
  point: apply(lookup(frames, "world", "cam"), [1, 0, 0]),
  camInLaser: [...camInLaser.t, ...camInLaser.q],
  otherTree: lookup(frames, "world", "island"), loop: toRoot(frames, "a"),
  rows: treeRows(new Map([...frames].slice(0, 4))).map((r) => `${r.depth}:${r.name}`),
  slash: frameId("//base_link"),
  invertTwice: (() => { const i = invert(invert(frames.get("cam").T)); return [...i.t, ...i.q]; })(),
};
const store = new FrameStore();
const ts = (parent, child, secs) => ({ header: { stamp: { secs, nsecs: 0 }, frame_id: parent }, child_frame_id: child, transform: { translation: { x: 1, y: 0, z: 0 }, rotation: { x: 0, y: 0, z: 0, w: 2 } } });
for (let i = 0; i <= 10; i++) store.add(ts("/world", "/base", 100 + i), false, 50 + i * 0.1);
store.add(ts("base", "laser", 0), true, 51);
store.add(ts("x", "x", 0), false, 51);
for (let i = 0; i < 2100; i++) store.add(ts("world", "f" + i, 1), false, 52);
out.tf.store = { rate: store.rate("base", 51), staticRate: store.rate("laser", 51), parent: store.frames.get("base").parent, q: store.frames.get("base").T.q, frames: store.frames.size, self: store.frames.has("x") };

// --- actions --------------------------------------------------------------------------------------------
const ag = input.actionGoal;
const def = parseDefinition(ag.type, ag.definition);
const channels = [
  { topic: "/test_action/goal", schemaName: ag.type, schema: ag.definition },
  { topic: "/test_action/status", schemaName: "actionlib_msgs/GoalStatusArray", schema: "" },
  { topic: "/test_action/feedback", schemaName: "actionlib/TestActionFeedback", schema: "" },
  { topic: "/half/goal", schemaName: ag.type, schema: "" },
  { topic: "/not/goal", schemaName: "std_msgs/String", schema: "" },
  { topic: "/not/status", schemaName: "actionlib_msgs/GoalStatusArray", schema: "" },
];
const goalType = def.types.get(def.root).find((f) => f.name === "goal").type;
const fields = leafFields(def, goalType);
const goal = {};
setPath(goal, fields[0].path, fieldValue(fields[0], "5"));
out.actions = {
  servers: actionServers(channels).map((s) => [s.name, s.type, Boolean(s.feedback), Boolean(s.result)]),
  goalId: goalId("/mrosd_web/page_x", 3, 1700000000.1234), stamp: stampOf(1700000000123),
  fields: fields.map((f) => [f.path.join("."), f.type, f.array]),
  bytes: b64(serialize(def, actionGoal(ag.id, goal, ag.ms))),
  errors: [tryOr(() => fieldValue(fields[0], "1.5")), tryOr(() => fieldValue(fields[0], "")), tryOr(() => fieldValue({ path: ["v"], type: "float64", array: -1 }, "{}"))],
};

// --- reconfigure ----------------------------------------------------------------------------------------
const cd = input.configDescription;
const desc = deserialize(parseDefinition(cd.type, cd.definition), Buffer.from(cd.body, "base64"));
out.reconfigure = {
  groups: plain(describe(desc)),
  literal: tryOr(() => parsePyLiteral(input.editMethod)),
  hostile: [
    "__import__('os').system('id')", "{'enum': [" + "[".repeat(100) + "]" .repeat(100) + "]}", "'" + "a".repeat(70000) + "'",
    "{'a': 1} trailing", "{'a' 1}", "(1, 2", "'unterminated",
  ].map((t) => tryOr(() => parsePyLiteral(t)).error ?? "parsed"),
  plainLiterals: plain(parsePyLiteral("{'s': 'it\\'s', 't': (1, -2.5e3, True, None, inf), \"u\": '\\x41\\u00e9'}")),
  protoKey: Object.getPrototypeOf(parsePyLiteral("{'__proto__': {'polluted': 1}}")) === Object.prototype && ({}).polluted === undefined,
  config: b64(serialize(parseDefinition(input.config.type, input.config.definition), configOf([
    { name: "i", type: "int", value: 7 }, { name: "d", type: "double", value: 0.5 }, { name: "b", type: "bool", value: true }, { name: "s", type: "str", value: "x" },
  ]))),
  values: [...configValues({ ints: [{ name: "a", value: 1 }], bools: [{ name: "b", value: false }] })],
  ranges: [hasRange({ type: "int", min: -10, max: 10 }), hasRange({ type: "int", min: -2147483648, max: 2147483647 }), hasRange({ type: "double", min: 0, max: Infinity }), hasRange({ type: "str", min: "", max: "" })],
};

// --- teleop ---------------------------------------------------------------------------------------------
const lim = { linear: 0.5, angular: 1.0 };
const tdef = parseDefinition("geometry_msgs/Twist", TWIST_DEF);
out.teleop = {
  upLeft: twistOf(-0.5, -1, lim), clamped: twistOf(5, 5, lim), nan: twistOf(NaN, NaN, lim),
  keys: [keysStick(new Set(["ArrowUp"])), keysStick(new Set(["ArrowUp", "ArrowDown", "ArrowLeft"]))],
  limits: [limitOf("0.8", 0.5), limitOf("-1", 0.5), limitOf("1e9", 0.5), limitOf("abc", 0.5)],
  bytes: b64(serialize(tdef, twistOf(-0.5, -1, lim))),
};
process.stdout.write(JSON.stringify(out));
