// Drives `nerf view` in headless Chromium as a person would: waits for the first full frame,
// drags to orbit and checks the picture changed, zooms with the wheel, records two keyframes,
// renders the downloaded camera path with `nerf render --camera-path`, and saves a screenshot.
//
// usage: node viewer.mjs NERF_BINARY [SCREENSHOT.png] [CONFIG]
// Chromium: $CHROMIUM, else /usr/bin/chromium. Everything stays on 127.0.0.1; the whole run is
// bounded by a 240 s timer.

import { chromium } from "playwright-core";
import { spawn, execFileSync } from "node:child_process";
import { mkdtempSync, rmSync, writeFileSync, existsSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";

const [binary, screenshot, config = "lego"] = process.argv.slice(2);
if (!binary) {
  console.error("usage: node viewer.mjs NERF_BINARY [SCREENSHOT.png] [CONFIG]");
  process.exit(2);
}
const scratch = mkdtempSync(join(tmpdir(), "nerf-browser-"));
let server = null;
let context = null;

function fail(message) {
  console.error(`browser test FAILED: ${message}`);
  cleanup();
  process.exit(1);
}

function cleanup() {
  if (server) server.kill();
  rmSync(scratch, { recursive: true, force: true });
}

const timer = setTimeout(() => fail("timed out after 240 s"), 240_000);

// Starts the server on a free loopback port and resolves to its URL.
function startServer() {
  server = spawn(binary, ["view", "--config", config, "--port", "0"], { stdio: ["ignore", "pipe", "inherit"] });
  return new Promise((resolve, reject) => {
    let out = "";
    server.stdout.on("data", chunk => {
      out += chunk;
      const m = out.match(/http:\/\/127\.0\.0\.1:\d+\//);
      if (m) resolve(m[0]);
    });
    server.on("exit", code => reject(new Error(`nerf view exited with ${code}`)));
  });
}

// Waits until the page has drawn the full frame of its newest request.
async function settled(page, afterFrames) {
  try {
    await page.waitForFunction(
      n => window.viewer.frames > n && window.viewer.drawnGen === window.viewer.gen,
      afterFrames,
      { timeout: 120_000, polling: 100 },
    );
  } catch (e) {
    const state = await page.evaluate(() => JSON.stringify({
      frames: window.viewer.frames, gen: window.viewer.gen, drawnGen: window.viewer.drawnGen,
      status: document.getElementById("status").textContent,
      error: document.getElementById("error").textContent,
    }));
    fail(`no new frame after ${afterFrames}: ${state}`);
  }
}

// Mean absolute difference (0..255) between the canvas now and the pixels saved as `saved`.
async function changeSince(page) {
  return page.evaluate(() => {
    const c = document.getElementById("view");
    const now = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
    const before = window.saved;
    let sum = 0;
    for (let i = 0; i < now.length; i++) sum += Math.abs(now[i] - before[i]);
    return sum / now.length;
  });
}

async function save(page) {
  await page.evaluate(() => {
    const c = document.getElementById("view");
    window.saved = c.getContext("2d").getImageData(0, 0, c.width, c.height).data.slice();
  });
}

async function main() {
  const url = await startServer();
  context = await chromium.launchPersistentContext(join(scratch, "profile"), {
    executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
    headless: true,
    args: ["--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking",
           "--disable-component-update", "--disable-sync"],
    viewport: { width: 960, height: 620 },
  });
  const page = context.pages()[0] || await context.newPage();
  page.on("pageerror", e => fail(`page error: ${e.message}`));
  await page.goto(url);
  await settled(page, 0);
  const status = await page.textContent("#status");
  if (!/frame time [\d.]+ s/.test(status) || !/samples evaluated [\d.]+ %/.test(status)) fail(`status shows ${status}`);
  console.log(`first frame: ${status.replace(/\n/g, "; ")}`);

  // Drag to orbit: the picture must change.
  await save(page);
  let frames = await page.evaluate(() => window.viewer.frames);
  const box = await page.locator("#view").boundingBox();
  const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
  await page.mouse.move(cx, cy);
  await page.mouse.down();
  for (let i = 1; i <= 8; i++) await page.mouse.move(cx + 15 * i, cy + 4 * i);
  await page.mouse.up();
  await settled(page, frames);
  const orbitChange = await changeSince(page);
  console.log(`after the drag: mean pixel change ${orbitChange.toFixed(2)} / 255`);
  if (!(orbitChange > 2)) fail("dragging did not change the view");

  // Wheel to zoom in: the picture changes again.
  await save(page);
  frames = await page.evaluate(() => window.viewer.frames);
  await page.mouse.wheel(0, -400);
  await settled(page, frames);
  const zoomChange = await changeSince(page);
  console.log(`after the wheel: mean pixel change ${zoomChange.toFixed(2)} / 255`);
  if (!(zoomChange > 2)) fail("the wheel did not change the view");

  // Two keyframes at 64×64, three frames per transition: a four-frame camera path.
  frames = await page.evaluate(() => window.viewer.frames);
  await page.selectOption("#res", "64");
  await settled(page, frames);
  await page.click("#addKey");
  frames = await page.evaluate(() => window.viewer.frames);
  // Clicking may have scrolled the page: find the canvas again.
  const box2 = await page.locator("#view").boundingBox();
  await page.mouse.move(box2.x + box2.width / 2, box2.y + box2.height / 2);
  await page.mouse.down();
  await page.mouse.move(box2.x + box2.width / 2 - 120, box2.y + box2.height / 2, { steps: 6 });
  await page.mouse.up();
  await settled(page, frames);
  await page.click("#addKey");
  await page.fill("#perTransition", "3");
  const [download] = await Promise.all([page.waitForEvent("download"), page.click("#download")]);
  const pathFile = join(scratch, "camera_path.json");
  await download.saveAs(pathFile);
  const out = join(scratch, "path");
  execFileSync(binary, ["render", "--config", config, "--camera-path", pathFile, "--out-dir", out], { stdio: "inherit" });
  for (const f of ["frame_0000.png", "frame_0003.png", "camera_path.gif"]) {
    if (!existsSync(join(out, f))) fail(`the recorded path did not render ${f}`);
  }
  if (existsSync(join(out, "frame_0004.png"))) fail("the recorded path has more than 4 frames");
  console.log("recorded camera path rendered: 4 frames");

  // Back to 256² for the screenshot.
  frames = await page.evaluate(() => window.viewer.frames);
  await page.selectOption("#res", "256");
  await settled(page, frames);
  if (screenshot) {
    await page.screenshot({ path: screenshot });
    console.log(`screenshot: ${screenshot}`);
  }
  await context.close();
}

main().then(() => {
  clearTimeout(timer);
  cleanup();
  console.log("browser test passed");
}).catch(e => fail(e.stack || String(e)));
