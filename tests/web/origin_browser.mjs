// Headless Chromium (Debian's /usr/bin/chromium, driven by playwright-core) as a victim's browser: open one URL,
// evaluate one function in that page (so what it opens carries that page's Origin), print the JSON result.
// Usage: node origin_browser.mjs <url> <expression of an async function> <JSON argument>
// The names *.test resolve to 127.0.0.1 (a page "from another site" on this machine, and a DNS-rebinding name).
import { chromium } from "playwright-core";

const [url, expr, arg] = process.argv.slice(2);
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  headless: true,
  args: [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--no-first-run", "--disable-sync",
    "--host-resolver-rules=MAP *.test 127.0.0.1",
  ],
});
try {
  const page = await browser.newPage();
  const response = await page.goto(url);
  const result = await page.evaluate(`(${expr})(${arg})`);
  process.stdout.write(JSON.stringify({ status: response ? response.status() : null, result }) + "\n");
} catch (e) {
  process.stdout.write(JSON.stringify({ error: String(e) }) + "\n");
} finally {
  await browser.close();
}
