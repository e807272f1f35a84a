// Drives the dashboard in headless Chromium (Debian's, through playwright-core) against a live
// coordinator that tests/dashboard_browser_test.cpp started:
//   node dashboard.cjs URL TOKEN RUNNING_JOB QUEUED_JOB SCREENSHOT_DIR
// It logs in with the token, opens the running job, takes two screenshots of the preview at
// different moments and checks they differ, presses Cancel on the queued job (accepting the
// confirmation) and checks through the API that it was cancelled, then waits for the running
// job's tile map to reach all done and checks the page's numbers against the API's. Exits 1
// naming the first check that failed.
"use strict";
const { chromium } = require("playwright-core");
const fs = require("node:fs");
const path = require("node:path");

const [url, token, runningJob, queuedJob, shots] = process.argv.slice(2);
const chromiumPath = ["/usr/bin/chromium", "/usr/bin/chromium-browser"].find(fs.existsSync);

function fail(message) {
  console.error(`dashboard test: ${message}`);
  process.exit(1);
}

async function apiJson(p) {
  const response = await fetch(url + p, { headers: { Authorization: `Bearer ${token}` } });
  if (!response.ok) fail(`${p}: HTTP ${response.status}`);
  return response.json();
}

async function waitFor(what, predicate, seconds = 60) {
  const end = Date.now() + seconds * 1000;
  while (Date.now() < end) {
    if (await predicate()) return;
    await new Promise((r) => setTimeout(r, 100));
  }
  fail(`timed out waiting for ${what}`);
}

(async () => {
  if (!chromiumPath) fail("no Chromium (deploy/install-deps.sh installs Debian's chromium)");
  const browser = await chromium.launch({ executablePath: chromiumPath, headless: true,
                                          args: ["--no-sandbox"] });
  try {
    const page = await browser.newPage({ viewport: { width: 1280, height: 900 } });
    page.on("dialog", (dialog) => dialog.accept());
    await page.goto(url + "/");
    await page.fill("#token", token);
    await page.click("#login button");
    await waitFor("the jobs list", async () =>
      (await page.locator(`#jobs tr[data-job="${runningJob}"]`).count()) === 1);
    await page.click(`#jobs tr[data-job="${runningJob}"]`);

    // The preview fills in: a later preview, once a tile has finished since the first, differs
    // from the first. (The page refetches the preview on every job update, so a new version need
    // not hold a new tile: wait for later versions, for up to a minute of twelve 1-2 s tiles.)
    const version = async () => Number(await page.getAttribute("#preview", "data-version") || 0);
    await waitFor("a first preview", async () => (await version()) >= 1);
    await new Promise((r) => setTimeout(r, 300));  // the image is decoded and drawn
    const first = await page.locator("#preview").screenshot();
    let seen = await version();
    let changed = false;
    for (const end = Date.now() + 60000; !changed && Date.now() < end;) {
      await waitFor("a later preview", async () => (await version()) > seen);
      seen = await version();
      await new Promise((r) => setTimeout(r, 300));  // the new image is decoded and drawn
      changed = Buffer.compare(first, await page.locator("#preview").screenshot()) !== 0;
    }
    if (!changed) fail("the preview did not change in a minute of rendering");

    // The convergence plot draws the API's error estimate.
    await waitFor("the convergence plot", async () =>
      Number(await page.getAttribute("#convergence", "data-points") || 0) >= 3);
    await page.screenshot({ path: path.join(shots, "dashboard-running.png") });

    // The rendering worker shows a throughput.
    await waitFor("a worker's throughput", async () =>
      Number((await page.textContent("#workers td.rate") || "0").replace(/\D/g, "")) > 0);

    // Cancel the queued job from the page (it waits behind the running one).
    await page.click(`#jobs tr[data-job="${queuedJob}"] button.cancel`);
    await waitFor("the cancel to reach the API", async () =>
      (await apiJson(`/api/v1/jobs/${queuedJob}`)).state === "JOB_STATE_CANCELLED");
    await waitFor("the page to show it cancelled", async () =>
      (await page.textContent(`#jobs tr[data-job="${queuedJob}"] td:nth-child(3)`)) === "cancelled");

    // The tile map reaches all done, and says what the API says.
    await waitFor("the tile map to reach done", async () => {
      const states = await page.getAttribute("#tiles", "data-states");
      return states && /^d+$/.test(states);
    }, 120);
    const tiles = await apiJson(`/api/v1/jobs/${runningJob}/tiles`);
    const shown = await page.getAttribute("#tiles", "data-states");
    if (shown !== tiles.states) fail(`tile map ${shown} but the API says ${tiles.states}`);
    const convergence = (await apiJson(`/api/v1/jobs/${runningJob}/convergence`)).points;
    const drawn = Number(await page.getAttribute("#convergence", "data-last"));
    const final = convergence[convergence.length - 1].relativeError;
    if (Math.abs(drawn - final) > 1e-12 * final) fail(`plotted error ${drawn}, API ${final}`);
    const counts = await page.textContent("#tile-counts");
    if (!counts.startsWith(`${tiles.states.length} done`)) fail(`tile counts read "${counts}"`);
    await waitFor("the job to show done", async () =>
      (await page.textContent(`#jobs tr[data-job="${runningJob}"] td:nth-child(3)`)) === "done");
    const job = await apiJson(`/api/v1/jobs/${runningJob}`);
    if (job.state !== "JOB_STATE_DONE") fail(`the API says ${job.state}`);
    await waitFor("the report", async () => (await page.textContent("#report")).includes("integrator"));

    await page.screenshot({ path: path.join(shots, "dashboard-done.png") });
    console.log("dashboard test: ok");
  } finally {
    await browser.close();
  }
})().catch((e) => fail(e.stack || String(e)));
