// Headless Chromium on mrosd's page for the drive tabs' tests (tests/web/test_web_page_drive*.py): the commands of
// page_browser.mjs ({"cmd":"goto"|"eval"|"shot"}) plus real input and closing the tab:
//   {"cmd":"mouse","action":"move"|"down"|"up","x":...,"y":...}  {"cmd":"key","action":"down"|"up","key":"ArrowUp"}
//   {"cmd":"closetab"} (the page's pagehide runs, as when a user closes it; a blank tab takes its place)  {"cmd":"close"}
import { createInterface } from "node:readline";
import { chromium } from "playwright-core";

const out = (obj) => process.stdout.write(JSON.stringify(obj) + "\n");
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  headless: true,
  args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--no-first-run", "--disable-sync"],
});
const context = await browser.newContext({ viewport: { width: 1100, height: 800 } });
let page;
async function openPage() {
  page = await context.newPage();
  page.on("console", (m) => out({ event: "console", text: m.text() }));
  page.on("pageerror", (e) => out({ event: "pageerror", message: String(e) }));
}
await openPage();
out({ event: "ready" });

const run = async (c) => {
  if (c.cmd === "goto") { await page.goto(c.url); return null; }
  if (c.cmd === "eval") return await page.evaluate(c.expr);
  if (c.cmd === "shot") { await page.screenshot({ path: c.path, fullPage: c.full ?? false }); return c.path; }
  if (c.cmd === "mouse") {
    if (c.action === "move") await page.mouse.move(c.x, c.y, { steps: c.steps ?? 1 });
    else await page.mouse[c.action]();
    return null;
  }
  if (c.cmd === "key") { await page.keyboard[c.action](c.key); return null; }
  if (c.cmd === "closetab") { await page.close({ runBeforeUnload: true }); await openPage(); return null; }
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
