// End-to-end test of the browser viewer (service-api.md "GET /") in headless Chromium.
// Started by tests/browser/run.sh, which builds and starts `glimpse serve`; see README.md.
//
//   node viewer.test.cjs BASE_URL SCREENSHOT.png [TOKEN]
//
// What it checks, in order (each step fails the run with a message):
//  1. with a token: without it the page shows the 401 error; with it the examples load;
//  2. a scene error (negative radius) is shown next to its JSON path and selected in the
//     textarea;
//  3. an example (or, if none is bundled, a built-in scene) at an overridden small size is
//     submitted; at least two frames arrive over the WebSocket, progress is shown, the
//     final statistics table fills;
//  4. switching to the distance layer changes the image and shows the JND legend;
//  5. `/?job=ID` reopens the finished job; the jobs list shows it;
//  6. the cancel button cancels a running job;
//  7. no uncaught page error at any point. A screenshot goes to SCREENSHOT.png.
// What a person needs besides (each with a screenshot beside SCREENSHOT.png, suffixed):
//  - with no job open the state badge is hidden and the download links are disabled;
//  - an example fills the editor as its file is written, and the draft survives a reload;
//  - the job header shows size, samples and mode from the start; "Edit and re-render"
//    brings back the job's scene as it was submitted (GET /v1/jobs/{id}/scene);
//  - a scene with a lamp facing away from everything shows its warning, also when the job
//    is opened again later, and the jobs list marks it;
//  - a large image's preview comes as a smaller PNG and is shown at the image's size;
//  - a width-only size override keeps the scene's aspect;
//  - on a narrow screen an open job's picture comes before the editor;
//  - the time left reads as a range, "finishing" or "estimating", never "0 ms";
//  - downloads are named after the job;
//  - the iteration slider shows an earlier iteration's picture and comes back; after a
//    reload it spans the iterations the server kept, and an earlier iteration's classes
//    layer differs from the final (flat) one, with its legend and the slider in view at
//    1440×900.
// Uploads: a .glb, a .gltf (packed into a zip bundle by the page) and a zip of a
// pbrt scene with its PLY files are each named before Render, sent with the size and
// samples overrides as query parameters, stream and finish (screenshots -glb, -gltf,
// -pbrt-zip); the import's warnings are shown; a truncated .glb is refused with the
// server's message naming the file (-upload-refused).
"use strict";

const fs = require("fs");
const os = require("os");
const path = require("path");
const { chromium } = require("playwright-core");

const [base, shotPath, token] = process.argv.slice(2);
if (!base || !shotPath) {
  console.error("usage: node viewer.test.cjs BASE_URL SCREENSHOT.png [TOKEN]");
  process.exit(2);
}
const auth = token ? { Authorization: "Bearer " + token } : {};
const T = (s) => s * 1000;

// Used when the server bundles no example, and as the shape of the error case.
const FALLBACK_SCENE = {
  version: 1, name: "browser-test",
  image: { width: 96, height: 72 },
  camera: { position: [0, 0.5, 5], look_at: [0, 0, 0], up: [0, 1, 0], fov_y: 40 },
  materials: {
    white: { type: "diffuse", albedo: [0.7, 0.7, 0.7] },
    floor: { type: "diffuse", texture: { type: "checker", scale: 0.5, a: [0.8, 0.1, 0.1], b: [0.1, 0.1, 0.8] } },
  },
  objects: [
    { type: "sphere", center: [0, 0, 0], radius: 1, material: "white" },
    { type: "quad", corner: [-3, -1, 3], edge_u: [6, 0, 0], edge_v: [0, 0, -6], material: "floor" },
  ],
  lights: [
    { type: "point", position: [2, 4, 5], intensity: [50, 50, 50] },
    { type: "environment", radiance: [0.1, 0.1, 0.1] },
  ],
  render: { mode: "progressive", samples_per_pixel: 4, max_bounces: 2, seed: 1 },
  progressive: { force_loop: true },
};

// A job that keeps the single worker busy until we cancel it, so that the viewer's job
// is queued behind it and its stream is open before its first frame: without this a
// small render can finish before the WebSocket connects (then only the last frame shows).
const BLOCKER_SCENE = Object.assign({}, FALLBACK_SCENE, {
  name: "browser-test-blocker", image: { width: 1024, height: 768 },
  render: { mode: "reference", samples_per_pixel: 256, max_bounces: 4, seed: 2 },
});

async function api(method, p, body) {
  const res = await fetch(base + p, {
    method, headers: Object.assign({ "Content-Type": "application/json" }, auth),
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const text = await res.text();
  let json = null;
  try { json = JSON.parse(text); } catch (_) { /* not JSON */ }
  return { status: res.status, json, text };
}

// Upload fixtures in a temporary folder: the Khronos Box (tests/public-scenes/gltf-box) as
// its own .gltf and as a .glb built here (the data URI's bytes as the BIN chunk, glTF 2.0
// §4.4), that .glb cut short, and a zip of Veach's bidir room (scenes/imported/veach-bidir:
// its pbrt file and PLY meshes) with stored entries.
function fixtures() {
  const repo = path.resolve(__dirname, "../..");
  const dir = fs.mkdtempSync(path.join(os.tmpdir(), "glimpse-uploads-"));
  const gltfPath = path.join(repo, "tests/public-scenes/gltf-box/Box.gltf");
  const gltf = JSON.parse(fs.readFileSync(gltfPath, "utf8"));
  const uri = gltf.buffers[0].uri;
  const bin = Buffer.from(uri.slice(uri.indexOf(",") + 1), "base64");
  delete gltf.buffers[0].uri;
  const pad = (b, c) => Buffer.concat([b, Buffer.alloc((4 - (b.length % 4)) % 4, c)]);
  const json = pad(Buffer.from(JSON.stringify(gltf)), 0x20), data = pad(bin, 0);
  const chunk = (type, body) => {
    const h = Buffer.alloc(8);
    h.writeUInt32LE(body.length, 0); h.writeUInt32LE(type, 4);
    return Buffer.concat([h, body]);
  };
  const body = Buffer.concat([chunk(0x4e4f534a, json), chunk(0x004e4942, data)]);
  const head = Buffer.alloc(12);
  head.write("glTF", 0); head.writeUInt32LE(2, 4); head.writeUInt32LE(12 + body.length, 8);
  const glb = Buffer.concat([head, body]);
  const out = {
    dir, gltf: path.join(dir, "Box.gltf"), glb: path.join(dir, "Box.glb"),
    truncated: path.join(dir, "Box-truncated.glb"), zip: path.join(dir, "veach-bidir.zip"),
  };
  fs.copyFileSync(gltfPath, out.gltf);
  fs.writeFileSync(out.glb, glb);
  fs.writeFileSync(out.truncated, glb.subarray(0, glb.length - 20));
  const bidir = path.join(repo, "scenes/imported/veach-bidir");
  const entries = [["scene-v4.pbrt", fs.readFileSync(path.join(bidir, "scene-v4.pbrt"))]];
  for (const f of fs.readdirSync(path.join(bidir, "models")).sort())
    entries.push(["models/" + f, fs.readFileSync(path.join(bidir, "models", f))]);
  fs.writeFileSync(out.zip, zipStored(entries));
  return out;
}

// A zip of stored entries (APPNOTE 6.3), CRC-32 from zlib.
function zipStored(entries) {
  const zlib = require("zlib");
  const local = [], central = [];
  let offset = 0;
  for (const [name, data] of entries) {
    const n = Buffer.from(name);
    const h = Buffer.alloc(26);
    h.writeUInt16LE(20, 0); h.writeUInt16LE(0x0800, 2); h.writeUInt16LE(0, 4);
    h.writeUInt16LE(0, 6); h.writeUInt16LE(0x21, 8); h.writeUInt32LE(zlib.crc32(data), 10);
    h.writeUInt32LE(data.length, 14); h.writeUInt32LE(data.length, 18);
    h.writeUInt16LE(n.length, 22); h.writeUInt16LE(0, 24);
    const sig = (v) => { const b = Buffer.alloc(4); b.writeUInt32LE(v, 0); return b; };
    local.push(sig(0x04034b50), h, n, data);
    // comment length, disk, internal attributes, then the Unix mode and the local offset
    const tail = Buffer.alloc(14);
    tail.writeUInt32LE((0o100644 << 16) >>> 0, 6); tail.writeUInt32LE(offset, 10);
    const made = Buffer.alloc(2); made.writeUInt16LE(0x0314, 0);
    central.push(sig(0x02014b50), made, h, tail, n);
    offset += 30 + n.length + data.length;
  }
  const dir = Buffer.concat(central);
  const end = Buffer.alloc(22);
  end.writeUInt32LE(0x06054b50, 0); end.writeUInt16LE(entries.length, 8);
  end.writeUInt16LE(entries.length, 10); end.writeUInt32LE(dir.length, 12);
  end.writeUInt32LE(offset, 16);
  return Buffer.concat([...local, dir, end]);
}

function check(cond, msg) {
  if (!cond) throw new Error("FAIL: " + msg);
  console.log("ok - " + msg);
}

async function main() {
  const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), "glimpse-chromium-"));
  const context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
    headless: true, // adds --headless
    args: ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
      "--disable-background-networking", "--disable-component-update", "--disable-sync"],
    viewport: { width: 1280, height: 900 },
  });
  const pageErrors = [];
  const page = context.pages()[0] || (await context.newPage());
  page.on("pageerror", (e) => pageErrors.push(String(e)));
  page.on("console", (m) => {
    if (m.type() === "error" && !/Failed to load resource/.test(m.text())) console.log("  [console] " + m.text());
  });
  // Expected 4xx (401 before the token, 422 for the bad scene, 404 for a frame that does
  // not exist yet) are listed for the log, not failed on.
  page.on("response", (r) => { if (r.status() >= 400) console.log("  [http " + r.status() + "] " + r.url().replace(base, "")); });
  page.setDefaultTimeout(T(30));
  let blockerId = null;
  try {
    // 1. token handling ------------------------------------------------------------------
    await page.goto(base + "/");
    if (token) {
      await page.waitForSelector("#error.visible");
      const msg = await page.textContent("#error");
      check(/token/i.test(msg), "without the token the page says why (" + msg.trim().slice(0, 60) + ")");
      await page.fill("#token", token);
      await page.reload();
      check(await page.inputValue("#token") === token, "the token is kept in localStorage across reloads");
    }
    await page.waitForFunction(() => {
      const o = document.querySelector("#example-select option");
      return o && !/loading/.test(o.textContent);
    });
    check(!(await page.isVisible("#error.visible")), "examples load without an error");
    check(!(await page.isVisible("#job-state")), "no state badge beside 'No job open'");
    check((await page.getAttribute("#download-png", "aria-disabled")) === "true"
      && !(await page.getAttribute("#download-png", "href")), "download links are disabled with no job open");
    await page.screenshot({ path: shotPath.replace(/\.png$/, "-empty.png"), fullPage: true });

    // 2. a scene error is located in the pasted JSON ---------------------------------------
    const bad = JSON.parse(JSON.stringify(FALLBACK_SCENE));
    bad.objects[0].radius = -2;
    await page.fill("#scene-text", JSON.stringify(bad, null, 2));
    await page.click("#submit");
    await page.waitForSelector("#error.visible");
    const errPath = await page.textContent("#error-path");
    check(errPath === "objects[0].radius", "422 shows the field path (" + errPath + ")");
    const selected = await page.$eval("#scene-text", (t) => t.value.slice(t.selectionStart, t.selectionEnd));
    check(/"radius":\s*-2/.test(selected), "the faulty field is selected in the textarea (" + selected + ")");

    // 3. submit an example (small) and watch it refine --------------------------------------
    const examples = (await api("GET", "/v1/examples")).json.examples || [];
    let sceneText;
    if (examples.length) {
      // The smallest bundled example, at 96x72 (size override fields) and few samples.
      const px = (e) => (e.scene.image ? e.scene.image.width * e.scene.image.height : 1e12);
      const k = examples.reduce((best, e, i) => (px(e) < px(examples[best]) ? i : best), 0);
      await page.selectOption("#example-select", String(k));
      const asWritten = await page.inputValue("#scene-text");
      check(typeof examples[k].text === "string" && asWritten === examples[k].text,
        "picking example '" + examples[k].name + "' fills the editor with the file as written ("
        + asWritten.split("\n").length + " lines)");
      check(asWritten.indexOf('"version"') < asWritten.indexOf('"objects"'),
        "its keys keep the file's order (version before objects, not alphabetised)");
      await page.reload();
      await page.waitForFunction(() => document.querySelector("#scene-text").value.length > 0);
      check((await page.inputValue("#scene-text")) === asWritten, "the draft survives a reload");
      const loaded = JSON.parse(asWritten);
      loaded.render = Object.assign({}, loaded.render, {
        samples_per_pixel: Math.min((loaded.render && loaded.render.samples_per_pixel) || 4, 4),
      });
      // At 4 spp an example's paths can be cheap enough to be traced whole in one frame;
      // the slider and layer checks need the loop's iterations.
      loaded.progressive = Object.assign({}, loaded.progressive, { force_loop: true });
      sceneText = JSON.stringify(loaded, null, 2);
    } else {
      console.log("note - the server bundles no example; using a built-in scene");
      sceneText = JSON.stringify(FALLBACK_SCENE, null, 2);
    }
    await page.fill("#scene-text", sceneText);
    await page.fill("#width-override", "96");
    await page.fill("#height-override", "72");

    const blocker = await api("POST", "/v1/jobs", BLOCKER_SCENE);
    check(blocker.status === 201, "blocker job accepted (" + blocker.status + ")");
    blockerId = blocker.json.id;
    await page.click("#submit");
    await page.waitForFunction(() => /^[0-9a-f-]{8,}/i.test(document.querySelector("#job-id").textContent));
    const jobId = (await page.textContent("#job-id")).trim();
    check(!(await page.isVisible("#error.visible")), "the scene is accepted (job " + jobId + ")");
    check(new URL(page.url()).searchParams.get("job") === jobId, "the address bar carries ?job=ID");
    await page.waitForFunction(() => /96 × 72 px/.test(document.querySelector("#job-summary").textContent));
    const summary = await page.textContent("#job-summary");
    check(/4 samples per pixel/.test(summary) && /mode/.test(summary) && Number(await page.$eval("#frame-img", (i) => i.dataset.frames)) === 0,
      "the header shows size, samples and mode before the first frame (" + summary + ")");
    const etaQueued = await page.textContent("#eta");
    check(!/^0 ms$/.test(etaQueued), "the time left of a waiting job is not '0 ms' (" + etaQueued + ")");
    await page.waitForFunction(() => document.querySelector("#status").textContent === "Streaming.");
    const cancelled = await api("POST", "/v1/jobs/" + blockerId + "/cancel");
    check(cancelled.status === 202, "blocker cancelled (" + cancelled.status + ")");
    blockerId = null;

    await page.waitForFunction(() => Number(document.querySelector("#frame-img").dataset.frames) >= 2,
      null, { timeout: T(120) });
    check(true, "at least two frames arrived over the WebSocket");
    await page.waitForFunction(() => document.querySelectorAll("#stats th").length >= 8, null, { timeout: T(120) });
    const statsText = await page.textContent("#stats");
    check(/pixels traced/.test(statsText) && /total time/.test(statsText), "the final statistics table is shown");
    check((await page.textContent("#job-state")) === "finished", "the job succeeded (badge: finished)");
    check((await page.textContent("#eta")) !== "0 ms", "the time left of a finished job is not '0 ms'");
    const dl = await page.getAttribute("#download-png", "download");
    check(dl.endsWith(".png") && !dl.startsWith("glimpse-") && dl.length < 60
      && (await page.getAttribute("#download-png", "aria-disabled")) === "false",
      "the PNG download is live and named after the job (" + dl + ")");
    await page.click("#edit-job");
    const back = await page.inputValue("#scene-text");
    const submitted = (await api("GET", "/v1/jobs/" + jobId + "/scene")).text;
    check(back === submitted && JSON.parse(back).image.width === 96,
      "'Edit and re-render' brings back the job's scene as submitted");
    const iteration = await page.textContent("#iteration");
    const fraction = await page.textContent("#pixel-fraction");
    check(/^\d+$/.test(iteration) && /%$/.test(fraction), "iteration " + iteration + ", pixels " + fraction);
    check(await page.$$eval("#iterations tr", (r) => r.length) >= 2, "per-iteration timings are listed");
    check(Number(iteration) === (await page.$$eval("#stats th", (ths) => {
      const th = ths.find((t) => t.textContent === "iterations");
      return th ? Number(th.nextElementSibling.textContent) : -1;
    })), "the iterations card agrees with the statistics (" + iteration + ")");
    const frames = await page.$eval("#frame-img", (i) => Number(i.dataset.frames));
    console.log("  frames received: " + frames);
    // The iteration slider goes back to the first picture and forward to the last.
    check(!(await page.isDisabled("#iteration-slider")), "the iteration slider is live after " + frames + " frames");
    const latestSrc = await page.getAttribute("#frame-img", "src");
    await page.$eval("#iteration-slider", (sl) => { sl.value = "0"; sl.dispatchEvent(new Event("input")); });
    await page.waitForFunction((old) => {
      const i = document.querySelector("#frame-img");
      return i.src !== old && i.dataset.shown === "0" && i.complete && i.naturalWidth > 0;
    }, latestSrc);
    const shownLabel = await page.textContent("#iteration-shown");
    check(/^iteration 1 of \d+$/.test(shownLabel), "moving it shows an earlier iteration (" + shownLabel + ")");
    await page.screenshot({ path: shotPath.replace(/\.png$/, "-slider.png"), fullPage: false });
    await page.$eval("#iteration-slider", (sl) => { sl.value = sl.max; sl.dispatchEvent(new Event("input")); });
    check(/latest/.test(await page.textContent("#iteration-shown")), "and back to the latest");

    // 4. the distance layer -----------------------------------------------------------------
    await page.waitForFunction(() => {
      const i = document.querySelector("#frame-img");
      return i.dataset.layer === "image" && i.complete && i.naturalWidth > 0;
    });
    const imageShot = await page.locator("#frame-img").screenshot();
    const imageSrc = await page.getAttribute("#frame-img", "src");
    await page.check("#layer-distance");
    await page.waitForFunction((old) => {
      const i = document.querySelector("#frame-img");
      return i.dataset.layer === "distance" && i.src !== old && i.complete && i.naturalWidth > 0;
    }, imageSrc);
    const distanceShot = await page.locator("#frame-img").screenshot();
    check(!imageShot.equals(distanceShot), "switching to the distance layer changes the image");
    check(await page.isVisible("#distance-scale"), "the distance legend (JND scale) is shown");
    const dims = await page.$eval("#frame-img", (i) => [i.naturalWidth, i.naturalHeight]);
    check(dims[0] === 96 && dims[1] === 72, "the size override was applied (" + dims.join("x") + ")");
    await page.check("#layer-classes");
    await page.waitForFunction(() => document.querySelector("#frame-img").dataset.layer === "classes");
    check(/complex/.test(await page.textContent("#legend")), "the classes legend is shown");
    await page.check("#layer-objects");
    await page.waitForFunction(() => document.querySelector("#frame-img").dataset.layer === "objects");
    check(/object/.test(await page.textContent("#legend")), "the objects legend is shown");
    await page.check("#layer-distance");
    await page.waitForFunction(() => document.querySelector("#frame-img").dataset.layer === "distance");
    // At 1440×900 the legend sits beside the picture, both in view.
    await page.setViewportSize({ width: 1440, height: 900 });
    await page.evaluate(() => document.querySelector("#frame-img").scrollIntoView({ block: "nearest" }));
    const [imgBox, legendBox] = await page.evaluate(() => ["#frame-img", "#legend"].map((q) => {
      const r = document.querySelector(q).getBoundingClientRect();
      return { left: r.left, right: r.right, top: r.top, bottom: r.bottom };
    }));
    check(legendBox.left >= imgBox.right - 1 && legendBox.bottom <= 900 && imgBox.bottom <= 900,
      "at 1440×900 the legend is beside the picture and both are in view");
    await page.screenshot({ path: shotPath.replace(/\.png$/, "-legend.png"), fullPage: false });
    await page.setViewportSize({ width: 1280, height: 900 });
    await page.screenshot({ path: shotPath, fullPage: true });
    console.log("  screenshot: " + shotPath);
    await page.check("#layer-image");
    await page.waitForFunction(() => document.querySelector("#frame-img").dataset.layer === "image");
    const imageShotPath = shotPath.replace(/\.png$/, "-image.png");
    await page.screenshot({ path: imageShotPath, fullPage: true });
    console.log("  screenshot: " + imageShotPath);
    // Responsive: on a phone-sized viewport the page has no horizontal scroll.
    await page.setViewportSize({ width: 390, height: 844 });
    const overflow = await page.evaluate(() => document.documentElement.scrollWidth - window.innerWidth);
    const mobileShotPath = shotPath.replace(/\.png$/, "-mobile.png");
    await page.screenshot({ path: mobileShotPath, fullPage: true });
    check(overflow <= 0, "no horizontal overflow at 390 px wide (" + overflow + " px); " + mobileShotPath);
    await page.setViewportSize({ width: 1280, height: 900 });

    // 5. reopen by address, jobs list ------------------------------------------------------------
    await page.goto(base + "/?job=" + encodeURIComponent(jobId));
    await page.waitForFunction(() => document.querySelectorAll("#stats th").length >= 8);
    await page.waitForFunction(() => {
      const i = document.querySelector("#frame-img");
      return i.complete && i.naturalWidth > 0;
    });
    check(true, "/?job=ID reopens the finished job with its frame and statistics");
    // After the reload the slider runs over the iterations the server kept, and an
    // earlier iteration's distance and classes layers still show where refinement went
    // (the final frame's are one flat colour: every triangle is final).
    await page.waitForFunction(() => !document.querySelector("#iteration-slider").disabled);
    const kept = JSON.parse((await api("GET", "/v1/jobs/" + jobId + "/iterations")).text).iterations;
    check(kept.length >= 2 && kept[0].iteration === 0
      && Number(await page.getAttribute("#iteration-slider", "max")) === kept.length - 1,
      "after a reload the slider spans the " + kept.length + " iterations the server kept");
    await page.check("#layer-classes");
    await page.waitForFunction(() => {
      const i = document.querySelector("#frame-img");
      return i.dataset.layer === "classes" && i.complete && i.naturalWidth > 0;
    });
    const finalClasses = await page.locator("#frame-img").screenshot();
    const finalSrc = await page.getAttribute("#frame-img", "src");
    await page.$eval("#iteration-slider", (sl) => { sl.value = "1"; sl.dispatchEvent(new Event("input")); });
    await page.waitForFunction(([old, n]) => {
      const i = document.querySelector("#frame-img");
      return i.src !== old && i.dataset.layer === "classes" && i.dataset.shown === String(n)
        && i.complete && i.naturalWidth > 0;
    }, [finalSrc, kept[1].iteration]);
    const earlyClasses = await page.locator("#frame-img").screenshot();
    check(!earlyClasses.equals(finalClasses), "an earlier iteration's classes layer differs from the final one");
    check(/iteration \d+ of \d+/.test(await page.textContent("#iteration-shown")), "the slider says which iteration is shown");
    await page.setViewportSize({ width: 1440, height: 900 });
    await page.evaluate(() => document.querySelector("#frame-img").scrollIntoView({ block: "nearest" }));
    const inView = await page.evaluate(() => ["#frame-img", "#legend", "#iteration-slider"].every((q) => {
      const r = document.querySelector(q).getBoundingClientRect();
      return r.top >= 0 && r.bottom <= window.innerHeight;
    }));
    check(inView, "at 1440×900 the earlier iteration, its legend and the slider are in view together");
    await page.screenshot({ path: shotPath.replace(/\.png$/, "-iterations.png"), fullPage: false });
    await page.setViewportSize({ width: 1280, height: 900 });
    await page.check("#layer-image");
    await page.$eval("#iteration-slider", (sl) => { sl.value = sl.max; sl.dispatchEvent(new Event("input")); });
    await page.waitForSelector(`#jobs tr[data-job="${jobId}"]`);
    check(true, "the jobs list shows the job");
    await page.click("#refresh-jobs");
    await page.click(`#jobs tr:not([data-job="${jobId}"]) button`);
    await page.waitForFunction((id) => document.querySelector("#job-id").textContent !== id, jobId);
    await page.click(`#jobs tr[data-job="${jobId}"] button`);
    await page.waitForFunction((id) => document.querySelector("#job-id").textContent === id, jobId);
    await page.waitForFunction(() => document.querySelectorAll("#stats th").length >= 8);
    check(true, "a job opens from the jobs list");
    const href = await page.getAttribute("#download-exr", "href");
    check(href === "/v1/jobs/" + jobId + "/frame?format=exr", "the EXR download link points at the job");

    // 5b. warnings, width-only override, narrow layout -------------------------------------------
    const away = JSON.parse(JSON.stringify(FALLBACK_SCENE));
    away.name = "lamp-facing-away";
    away.lights = [];
    away.objects.push({ type: "quad", corner: [-0.5, 5, -0.5], edge_u: [1, 0, 0], edge_v: [0, 0, -1], material: "lamp" });
    away.materials.lamp = { type: "emissive", radiance: [20, 20, 20] };
    await page.fill("#scene-text", JSON.stringify(away, null, 2));
    await page.fill("#width-override", "120");
    await page.fill("#height-override", "");
    await page.click("#submit");
    await page.waitForSelector("#warnings.visible");
    const warned = await page.textContent("#warnings");
    check(/objects\[2\]/.test(warned) && /faces away/.test(warned), "the lamp facing away is warned about (" + warned.slice(0, 70) + "…)");
    // Each frame swaps the image's source, so its size is read in the same poll that sees it
    // loaded: a later read may catch the next frame still loading (0 × 0).
    const wdims = await (await page.waitForFunction((previous) => {
      const i = document.querySelector("#frame-img");
      const mine = document.querySelector("#job-id").textContent !== previous;
      return mine && i.complete && i.naturalWidth > 0 && Number(i.dataset.frames) > 0
        && [i.naturalWidth, i.naturalHeight];
    }, jobId, { timeout: T(120) })).jsonValue();
    check(wdims[0] === 120 && wdims[1] === 90, "a width-only override keeps the aspect (" + wdims.join("x") + ")");
    await page.screenshot({ path: shotPath.replace(/\.png$/, "-warning.png"), fullPage: true });
    await page.setViewportSize({ width: 390, height: 844 });
    const order = await page.evaluate(() => [document.querySelector("#frame-img").getBoundingClientRect().top,
      document.querySelector("#scene-text").getBoundingClientRect().top]);
    check(order[0] < order[1] && order[0] < 844, "on a narrow screen the open job's picture comes first (" + order.map(Math.round).join(" < ") + ")");
    await page.screenshot({ path: shotPath.replace(/\.png$/, "-narrow-job.png"), fullPage: false });
    await page.setViewportSize({ width: 1280, height: 900 });

    // The job keeps its warnings: opened again from its address (no 201 this time) it still
    // shows them, and the jobs list marks it.
    const warnedId = (await page.textContent("#job-id")).trim();
    await page.goto(base + "/?job=" + encodeURIComponent(warnedId));
    await page.waitForFunction(() => /faces away/.test(document.querySelector("#job-warnings").textContent),
      null, { timeout: T(30) });
    await page.waitForSelector(`#jobs tr[data-job="${warnedId}"] .warned`, { timeout: T(10) });
    check(true, "opened again, the job still shows its warning, and the jobs list marks it");

    // 5b'. a large image's preview -----------------------------------------------------------------
    await page.fill("#scene-text", JSON.stringify(FALLBACK_SCENE, null, 2));
    await page.fill("#width-override", "640");
    await page.fill("#height-override", "480");
    // At 1:1 the picture is laid out at the image's size, whatever the PNG's.
    await page.click("#zoom-1");
    await page.click("#submit");
    // The preview's PNG is at most 512 px a side; the page shows it at the image's size,
    // smoothly (its pixels are not the image's). Read in the poll that sees it loaded: the
    // first iteration replaces it soon.
    const pv = await (await page.waitForFunction(() => {
      const i = document.querySelector("#frame-img");
      const r = i.getBoundingClientRect();
      return /preview/.test(document.querySelector("#iteration").textContent) && i.complete
        && i.naturalWidth > 0 && i.naturalWidth <= 512 && i.dataset.reduced === "true"
        && { natural: [i.naturalWidth, i.naturalHeight], box: [r.width, r.height],
          rendering: getComputedStyle(i).imageRendering, eta: document.querySelector("#eta").textContent };
    }, null, { timeout: T(60), polling: 5 })).jsonValue();
    check(!/waiting/.test(pv.eta), "a large image's first frame is called a preview, with no iteration done, and the job is no longer 'waiting' (" + pv.eta + ")");
    check(pv.natural[0] === 512 && pv.natural[1] === 384 && Math.round(pv.box[0]) === 640 && Math.round(pv.box[1]) === 480
      && pv.rendering === "auto",
      "the preview comes as a " + pv.natural.join("x") + " PNG and is shown at the image's 640x480 (" + pv.box.map(Math.round).join("x") + ", " + pv.rendering + ")");
    await page.screenshot({ path: shotPath.replace(/\.png$/, "-preview.png"), fullPage: false });
    await page.click("#zoom-fit");
    // The stream skips frames a slow page has not taken yet: the first one after the preview
    // may be a later iteration.
    await page.waitForFunction(() => /^[1-9][0-9]*$/.test(document.querySelector("#iteration").textContent),
      null, { timeout: T(120) });
    const after = await page.textContent("#iteration");
    const timingRows = await page.$$eval("#iterations tr", (rows) => rows.length);
    check(timingRows >= 1, "then the iterations are counted from 1 (" + after + " done, " + timingRows + " timing rows)");
    if (!(await page.isDisabled("#cancel"))) await page.click("#cancel");
    await page.waitForFunction(() => document.querySelector("#cancel").disabled, null, { timeout: T(60) });
    await page.fill("#height-override", "");
    await page.fill("#width-override", "");

    // 5c. zoom and pan, smooth downscaling -------------------------------------------------------
    const big = JSON.parse(JSON.stringify(FALLBACK_SCENE));
    big.name = "zoom-test";
    big.render = { mode: "reference", samples_per_pixel: 1, max_bounces: 1, seed: 1 };
    await page.fill("#scene-text", JSON.stringify(big, null, 2));
    await page.fill("#width-override", "400");
    await page.fill("#height-override", "");
    await page.click("#submit");
    await page.waitForFunction(() => {
      const i = document.querySelector("#frame-img");
      return i.complete && i.naturalWidth === 400 && document.querySelector("#job-state").textContent === "finished";
    }, null, { timeout: T(120) });
    await page.setViewportSize({ width: 390, height: 844 });
    // The layout settles after the resize; give the viewer's observer a moment to see it.
    await page.waitForFunction(() => {
      const i = document.querySelector("#frame-img");
      return i.getBoundingClientRect().width < 400 && getComputedStyle(i).imageRendering === "auto";
    }, null, { timeout: T(5) }).catch(() => {});
    const fit = await page.$eval("#frame-img", (i) => [i.getBoundingClientRect().width, getComputedStyle(i).imageRendering]);
    check(fit[0] < 400 && fit[1] === "auto", "fit shrinks the picture smoothly (" + Math.round(fit[0]) + " px, " + fit[1] + ")");
    await page.click("#zoom-1");
    const one = await page.$eval("#frame-img", (i) => Math.round(i.getBoundingClientRect().width));
    check(one === 400, "1:1 shows one image pixel per screen pixel (" + one + " px)");
    // In view first: the mouse only reaches what is on the screen.
    await page.locator("#stage").scrollIntoViewIfNeeded();
    const box = await page.locator("#stage").boundingBox();
    await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
    await page.mouse.down();
    await page.mouse.move(box.x + box.width / 2 - 60, box.y + box.height / 2, { steps: 5 });
    await page.mouse.up();
    const panned = await page.$eval("#stage", (st) => st.scrollLeft);
    check(panned > 20, "dragging pans the zoomed picture (" + panned + " px)");
    await page.click("#zoom-2");
    const two = await page.$eval("#frame-img", (i) => [Math.round(i.getBoundingClientRect().width), getComputedStyle(i).imageRendering]);
    check(two[0] === 800 && two[1] === "pixelated", "2:1 doubles it with visible pixels (" + two.join(", ") + ")");
    await page.screenshot({ path: shotPath.replace(/\.png$/, "-zoom.png"), fullPage: false });
    await page.click("#zoom-fit");
    await page.setViewportSize({ width: 1280, height: 900 });
    await page.fill("#width-override", "");

    // 5d. the live jobs list: place in line, size and mode, picture, delete, re-run ----------------
    const zoomId = (await page.textContent("#job-id")).trim();
    const hold = await api("POST", "/v1/jobs", BLOCKER_SCENE);
    blockerId = hold.json.id;
    const waiter = await api("POST", "/v1/jobs", Object.assign({}, FALLBACK_SCENE, { name: "browser-test-waiter" }));
    await page.waitForFunction((id) => {
      const tr = document.querySelector(`#jobs tr[data-job="${id}"]`);
      return tr && /1st in line/.test(tr.textContent);
    }, waiter.json.id, { timeout: T(10) });
    check(true, "the list shows a waiting job's place in line without a refresh");
    await api("POST", "/v1/jobs/" + waiter.json.id + "/cancel");
    await api("POST", "/v1/jobs/" + blockerId + "/cancel");
    blockerId = null;
    await page.waitForFunction((id) => {
      const tr = document.querySelector(`#jobs tr[data-job="${id}"]`);
      return tr && tr.dataset.state === "cancelled";
    }, waiter.json.id, { timeout: T(10) });
    check(true, "states change in the list by themselves");
    const row = `#jobs tr[data-job="${zoomId}"]`;
    await page.waitForSelector(row + " img.thumb");
    const sizeText = await page.textContent(row + " td.size");
    check(/400 × 300 px/.test(sizeText) && /reference/.test(sizeText), "a row shows size, samples and mode (" + sizeText + ") and a picture");
    await page.screenshot({ path: shotPath.replace(/\.png$/, "-jobs.png"), fullPage: true });
    await page.click(row + " button.rerun");
    await page.waitForFunction((id) => {
      const t = document.querySelector("#job-id").textContent;
      return t && t !== id;
    }, zoomId);
    const rerunId = (await page.textContent("#job-id")).trim();
    const a = (await api("GET", "/v1/jobs/" + zoomId + "/scene")).text;
    const b = (await api("GET", "/v1/jobs/" + rerunId + "/scene")).text;
    check(a === b, "Re-run submits the same scene as a new job");
    await page.click(row + " button.delete");
    await page.waitForFunction((sel) => !document.querySelector(sel), row, { timeout: T(10) });
    check((await api("GET", "/v1/jobs/" + zoomId)).status === 404, "Delete forgets the job");

    // 5e. uploads: a .glb, a .gltf (packed into a zip by the page), a zip of a pbrt scene with
    // its PLY files, and a refused one -----------------------------------------------------------
    const files = fixtures();
    await page.fill("#width-override", "64");
    await page.fill("#height-override", "");
    await page.fill("#spp-override", "4");
    const uploaded = async (file, what, shot) => {
      const before = (await page.textContent("#job-id")).trim();
      await page.setInputFiles("#scene-file", file);
      await page.waitForFunction((n) => document.querySelector("#upload-name").textContent.includes(n)
        && !document.querySelector("#submit").disabled, path.basename(file));
      const label = await page.textContent("#upload");
      check(await page.isVisible("#upload") && label.includes(path.basename(file)),
        what + ": the page names the upload before Render (" + label.trim().replace(/\s+/g, " ") + ")");
      await page.click("#submit");
      await page.waitForFunction((old) => {
        const t = document.querySelector("#job-id").textContent;
        return t && t !== old;
      }, before);
      check(!(await page.isVisible("#error.visible")), what + ": accepted as job " + (await page.textContent("#job-id")).trim());
      await page.waitForFunction(() => Number(document.querySelector("#frame-img").dataset.frames) >= 1,
        null, { timeout: T(120) });
      await page.waitForFunction(() => document.querySelector("#job-state").textContent === "finished"
        && document.querySelectorAll("#stats th").length >= 8, null, { timeout: T(120) });
      await page.waitForFunction(() => {
        const i = document.querySelector("#frame-img");
        return i.complete && i.naturalWidth > 0;
      });
      const frames = await page.$eval("#frame-img", (i) => Number(i.dataset.frames));
      const dims = await page.$eval("#frame-img", (i) => [i.naturalWidth, i.naturalHeight]);
      const spp = await page.textContent("#job-summary");
      check(dims[0] === 64 && /4 samples per pixel/.test(spp), what + ": streamed " + frames
        + " frame(s) and finished at " + dims.join("x") + " (" + spp + ")");
      const shotFile = shotPath.replace(/\.png$/, "-" + shot + ".png");
      await page.screenshot({ path: shotFile, fullPage: true });
      console.log("  screenshot: " + shotFile);
      return dims;
    };
    await uploaded(files.glb, "a .glb", "glb");
    const warnedGlb = await page.textContent("#warnings");
    check(/no light/.test(warnedGlb) && /camera/.test(warnedGlb),
      "the import's warnings are shown (" + warnedGlb.trim().slice(0, 80) + "…)");
    check(/no light/.test(await page.textContent("#job-warnings")), "and on the job");
    await uploaded(files.gltf, "a .gltf", "gltf");
    check(/packed into a zip/.test(await page.textContent("#upload")), "a .gltf is packed into a zip bundle by the page");
    const zipDims = await uploaded(files.zip, "a zip of a pbrt scene with its PLY files", "pbrt-zip");
    check(zipDims[1] === 64, "a width alone keeps the pbrt file's square aspect (" + zipDims.join("x") + ")");
    await page.setInputFiles("#scene-file", files.truncated);
    await page.waitForFunction(() => /Box-truncated/.test(document.querySelector("#upload-name").textContent)
      && !document.querySelector("#submit").disabled);
    await page.click("#submit");
    await page.waitForSelector("#error.visible");
    const refused = await page.textContent("#error");
    check(refused.includes("Box-truncated.glb was refused") && /truncated/.test(refused),
      "a refused upload shows the server's message naming the file (" + refused.trim().slice(0, 90) + ")");
    check(!(await page.isVisible("#warnings")), "and no warnings of the upload before it");
    await page.screenshot({ path: shotPath.replace(/\.png$/, "-upload-refused.png"), fullPage: true });
    await page.click("#upload-clear");
    check(!(await page.isVisible("#upload")), "the upload can be put aside for the editor");
    await page.fill("#spp-override", "");
    fs.rmSync(files.dir, { recursive: true, force: true });

    // 6. cancel from the page --------------------------------------------------------------------
    await page.fill("#width-override", "");
    await page.fill("#height-override", "");
    await page.fill("#scene-text", JSON.stringify(BLOCKER_SCENE));
    await page.click("#submit");
    await page.waitForFunction((old) => {
      const t = document.querySelector("#job-id").textContent;
      return t && t !== old;
    }, jobId);
    await page.waitForFunction(() => !document.querySelector("#cancel").disabled);
    await page.click("#cancel");
    await page.waitForFunction(() => document.querySelector("#job-state").textContent === "cancelled",
      null, { timeout: T(60) });
    check(true, "the cancel button cancels a running job");

    check(pageErrors.length === 0, "no uncaught page errors" + (pageErrors.length ? ": " + pageErrors.join("; ") : ""));
  } finally {
    if (blockerId) await api("POST", "/v1/jobs/" + blockerId + "/cancel").catch(() => {});
    await context.close();
    fs.rmSync(userDataDir, { recursive: true, force: true });
  }
}

main().then(() => console.log("viewer test passed" + (token ? " (with token)" : "")), (e) => {
  console.error(e && e.stack ? e.stack : String(e));
  process.exit(1);
});
