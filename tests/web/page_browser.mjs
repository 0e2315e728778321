// Headless Chromium (Debian's /usr/bin/chromium, driven by playwright-core) on mrosd's own page.
// Usage: node page_browser.mjs; one JSON command per stdin line, one JSON reply per stdout line:
// Every command but "tab" (open one more tab, returns its index) acts on tab "tab" (default 0):
//   {"cmd":"goto","url":...}  {"cmd":"eval","expr":...}  {"cmd":"viewport","width":...,"height":...}  {"cmd":"shot","path":...}  {"cmd":"heap"}  {"cmd":"close"}
import { createInterface } from "node:readline";
import { chromium } from "playwright-core";

const out = (obj) => process.stdout.write(JSON.stringify(obj) + "\n");
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  headless: true,
  handleSIGTERM: false, // ours below: playwright's closes the browser but leaves node running until SIGKILL
  args: [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--no-first-run", "--disable-sync",
  ],
});
process.on("SIGTERM", () => { browser.close().finally(() => process.exit(0)); });
const context = await browser.newContext({ viewport: { width: 1100, height: 760 } });
const tabs = [];
async function openTab() {
  const page = await context.newPage();
  const cdp = await context.newCDPSession(page);
  await cdp.send("Performance.enable");
  const index = tabs.length;
  page.on("console", (m) => out({ event: "console", tab: index, text: m.text() }));
  page.on("pageerror", (e) => out({ event: "pageerror", tab: index, message: String(e) }));
  tabs.push({ page, cdp });
  return index;
}
await openTab();
out({ event: "ready" });

const run = async (c) => {
  if (c.cmd === "tab") return await openTab();
  const { page, cdp } = tabs[c.tab ?? 0];
  if (c.cmd === "goto") { await page.goto(c.url); return null; }
  if (c.cmd === "eval") return await page.evaluate(c.expr);
  if (c.cmd === "viewport") { await page.setViewportSize({ width: c.width, height: c.height }); return null; }
  if (c.cmd === "shot") { await page.screenshot({ path: c.path, fullPage: false }); return c.path; }
  if (c.cmd === "heap") {
    await cdp.send("HeapProfiler.collectGarbage");
    const { metrics } = await cdp.send("Performance.getMetrics");
    return Object.fromEntries(metrics.map((m) => [m.name, m.value]));
  }
  throw new Error(`unknown command ${c.cmd}`);
};

const rl = createInterface({ input: process.stdin });
let chain = Promise.resolve();
rl.on("line", (line) => {
  const c = JSON.parse(line);
  chain = chain.then(async () => {
    if (c.cmd === "close") { await browser.close(); process.exit(0); }
    try { out({ reply: c.id, result: await run(c) }); } catch (e) { out({ reply: c.id, error: String(e) }); }
  });
});
rl.on("close", async () => { await browser.close(); process.exit(0); });
