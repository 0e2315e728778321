// Headless Chromium (Debian's /usr/bin/chromium, driven by playwright-core) running tests/web/roslib_page.html.
// Usage: node roslib_browser.mjs PAGE_URL ROSBRIDGE_URL; JSON commands on stdin, the page's events on stdout.
import { createInterface } from "node:readline";
import { chromium } from "playwright-core";

const [pageUrl, rosbridgeUrl] = process.argv.slice(2);
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
const page = await browser.newPage();
page.on("console", (m) => out({ event: "console", text: m.text() }));
page.on("pageerror", (e) => out({ event: "pageerror", message: String(e) }));
await page.goto(pageUrl);
await page.waitForFunction(() => window.ready === true, null, { timeout: 20000 });
await page.evaluate((url) => window.start(url), rosbridgeUrl);
out({ event: "loaded" });

let busy = false;
const timer = setInterval(async () => {
  if (busy) return;
  busy = true;
  try {
    for (const e of await page.evaluate(() => window.events.splice(0))) out(e);
  } catch (e) {
    out({ event: "error", message: String(e) });
  } finally {
    busy = false;
  }
}, 50);

const rl = createInterface({ input: process.stdin });
rl.on("line", async (line) => {
  const c = JSON.parse(line);
  if (c.cmd === "close") {
    clearInterval(timer);
    await browser.close();
    process.exit(0);
  }
  await page.evaluate((cmd) => window.command(cmd), c);
});
rl.on("close", async () => {
  clearInterval(timer);
  await browser.close();
  process.exit(0);
});
