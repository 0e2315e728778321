// Headless Chromium (Debian's /usr/bin/chromium, driven by playwright-core) as a victim's browser: for each job,
// open its URL in a fresh context and evaluate its function in that page (so what it opens carries that page's
// Origin); print the JSON list of results, one browser for all jobs.
// Usage: node origin_browser.mjs '[{"url": ..., "expr": "<an async function>", "arg": <its argument>}, ...]'
// The names *.test resolve to 127.0.0.1 (a page "from another site" on this machine, and a DNS-rebinding name).
import { chromium } from "playwright-core";

const jobs = JSON.parse(process.argv[2]);
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  headless: true,
  args: [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--no-first-run", "--disable-sync",
    "--host-resolver-rules=MAP *.test 127.0.0.1",
  ],
});
const results = [];
try {
  for (const { url, expr, arg } of jobs) {
    const context = await browser.newContext();
    try {
      const page = await context.newPage();
      const response = await page.goto(url);
      const result = await page.evaluate(`(${expr})(${JSON.stringify(arg)})`);
      results.push({ status: response ? response.status() : null, result });
    } catch (e) {
      results.push({ error: String(e) });
    } finally {
      await context.close();
    }
  }
} finally {
  process.stdout.write(JSON.stringify(results) + "\n");
  await browser.close();
}
