// The page's ROS 1 decoder (mrosd/web/static/ros1.js) under node: JSON cases on stdin, decoded JSON on stdout.
// Each case: {type, definition, body (base64)}; typed arrays come out as plain arrays, errors as {error}.
import { readFileSync } from "node:fs";
import { parseDefinition, deserialize } from "../../mrosd/web/static/ros1.js";

const plain = (v) => {
  if (ArrayBuffer.isView(v)) return Array.from(v);
  if (Array.isArray(v)) return v.map(plain);
  if (v && typeof v === "object") return Object.fromEntries(Object.entries(v).map(([k, x]) => [k, plain(x)]));
  return v;
};
const cases = JSON.parse(readFileSync(0, "utf8"));
const out = cases.map((c) => {
  try {
    return { value: plain(deserialize(parseDefinition(c.type, c.definition), Buffer.from(c.body, "base64"))) };
  } catch (e) {
    return { error: `${e.name}: ${e.message}` };
  }
});
process.stdout.write(JSON.stringify(out));
