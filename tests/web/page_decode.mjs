// The page's ROS 1 decoder (mrosd/web/static/ros1.js) under node: JSON cases on stdin, decoded JSON on stdout.
// Each case: {type, definition, body (base64)}; out: {value (typed arrays as plain arrays), again (the value
// serialized back by ros1.js, base64)} or {error}.
import { readFileSync } from "node:fs";
import { parseDefinition, deserialize, serialize } from "../../mrosd/web/static/ros1.js";

const plain = (v) => {
  if (ArrayBuffer.isView(v)) return Array.from(v);
  if (Array.isArray(v)) return v.map(plain);
  if (v && typeof v === "object") return Object.fromEntries(Object.entries(v).map(([k, x]) => [k, plain(x)]));
  return v;
};
const cases = JSON.parse(readFileSync(0, "utf8"));
const out = cases.map((c) => {
  try {
    const def = parseDefinition(c.type, c.definition);
    const value = deserialize(def, Buffer.from(c.body, "base64"));
    return { value: plain(value), again: Buffer.from(serialize(def, value)).toString("base64") };
  } catch (e) {
    return { error: `${e.name}: ${e.message}` };
  }
});
process.stdout.write(JSON.stringify(out));
