// Opens the viewer page in Debian's Chromium (headless, through playwright-core) and, once DONE_FILE exists (and the
// page shows WAIT_TEXT, if given), screenshots the page and the 3D panel's canvas into OUT_DIR, then opens the data
// source's "Problems" tab and reads every problem Studio lists with its details (problems.png), all in result.json.
//   node shoot.js URL OUT_DIR DONE_FILE TIMEOUT_S [WAIT_TEXT]
// CHROMIUM (default /usr/bin/chromium) names the browser; the profile is a fresh folder in OUT_DIR.
const fs = require("fs");
const path = require("path");
const { chromium } = require("playwright-core");

async function main() {
  const [url, outDir, doneFile, timeoutS, waitText] = process.argv.slice(2);
  const deadline = Date.now() + Number(timeoutS) * 1000;
  const context = await chromium.launchPersistentContext(path.join(outDir, "profile"), {
    executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
    headless: true,
    viewport: { width: 1400, height: 900 },
    args: ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
           "--disable-component-update", "--disable-sync"],
  });
  const result = { pageErrors: [], consoleErrors: [], requestsFailed: [] };
  try {
    const page = context.pages()[0] ?? (await context.newPage());
    page.on("pageerror", (e) => result.pageErrors.push(String(e)));
    page.on("console", (m) => { if (m.type() === "error") result.consoleErrors.push(m.text().slice(0, 500)); });
    page.on("requestfailed", (r) => result.requestsFailed.push(`${r.url()} ${r.failure()?.errorText}`));
    await page.goto(url);
    const canvas = page.locator("canvas").first();
    await canvas.waitFor({ timeout: Math.max(deadline - Date.now(), 1000) });
    while (!fs.existsSync(doneFile)) {
      if (Date.now() > deadline) throw new Error(`${doneFile} did not appear`);
      await page.waitForTimeout(250);
    }
    if (waitText) {
      await page.getByText(waitText).first().waitFor({ timeout: Math.max(deadline - Date.now(), 1000) });
    }
    await page.waitForTimeout(3000); // the last scene update drawn
    result.viewerError = await page.evaluate(() => document.body.getAttribute("data-viewer-error"));
    result.text = await page.evaluate(() => document.body.innerText);
    await page.screenshot({ path: path.join(outDir, "page.png") });
    await canvas.screenshot({ path: path.join(outDir, "canvas.png") });
    // the data source's Problems tab (studio-base's DataSourceSidebar): its count badge, and each problem's message
    // (a list item with a severity icon) and details (the dialog it opens)
    const tab = page.getByRole("tab", { name: /^Problems/ });
    result.problemsTab = await tab.innerText();
    await tab.click();
    await page.waitForTimeout(500);
    result.noProblemsShown = await page.getByText("No problems found").count() > 0;
    const icons = ["ErrorOutlineOutlinedIcon", "WarningAmberIcon", "InfoOutlinedIcon"];
    const items = page.locator(icons.map((i) => `.MuiListItemButton-root:has([data-testid="${i}"])`).join(", "));
    result.problems = [];
    for (let k = 0; k < await items.count(); k++) {
      const message = await items.nth(k).innerText();
      await items.nth(k).click();
      const dialog = page.getByRole("dialog");
      const details = await dialog.innerText({ timeout: 5000 }).catch((e) => `(no dialog: ${e})`);
      await page.keyboard.press("Escape");
      await dialog.waitFor({ state: "detached", timeout: 5000 }).catch(() => {});
      result.problems.push({ message, details: details.slice(0, 2000) });
    }
    await page.screenshot({ path: path.join(outDir, "problems.png") });
  } finally {
    fs.writeFileSync(path.join(outDir, "result.json"), JSON.stringify(result, null, 1));
    await context.close();
  }
}

main().catch((e) => { console.error(e); process.exit(1); });
