// Runs page.js in headless Chromium and answers JSON lines on stdin, one reply line each:
//   {"cmd": "load", "scene": {...}}          -> {"renderer": ..., "revision": ...}
//   {"cmd": "time", "frames": N, "shadows": b, "whole": b} -> {"ms": [...]}
//   {"cmd": "image", "mode": "shadowed"}       -> {"rgba": base64}
// Chromium draws WebGL through ANGLE on the host's EGL (Mesa llvmpipe here); the browser path
// comes from CHROMIUM (default /usr/bin/chromium): nothing is downloaded.
import http from "node:http";
import fs from "node:fs";
import path from "node:path";
import readline from "node:readline";
import { fileURLToPath } from "node:url";
import puppeteer from "puppeteer-core";

const root = path.dirname(fileURLToPath(import.meta.url));
const types = { ".html": "text/html", ".js": "text/javascript", ".mjs": "text/javascript" };
const server = http.createServer((req, res) => {
  const file = path.join(root, path.normalize(decodeURIComponent(new URL(req.url, "http://x").pathname)));
  if (!file.startsWith(root) || !fs.existsSync(file) || fs.statSync(file).isDirectory()) {
    res.writeHead(404).end();
    return;
  }
  res.writeHead(200, { "Content-Type": types[path.extname(file)] || "application/octet-stream" });
  fs.createReadStream(file).pipe(res);
});
await new Promise((ok) => server.listen(0, "127.0.0.1", ok));
const browser = await puppeteer.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  headless: true,
  args: ["--no-sandbox", "--use-gl=angle", "--use-angle=gl-egl", "--ignore-gpu-blocklist",
         "--disable-gpu-vsync", "--disable-frame-rate-limit"],
});
const page = await browser.newPage();
page.on("pageerror", (e) => process.stderr.write(`page error: ${e}\n`));
await page.goto(`http://127.0.0.1:${server.address().port}/index.html`);
await page.waitForFunction("window.benchReady === true");

const rl = readline.createInterface({ input: process.stdin, crlfDelay: Infinity });
for await (const line of rl) {
  if (!line.trim()) continue;
  const msg = JSON.parse(line);
  let reply;
  try {
    if (msg.cmd === "load") reply = await page.evaluate((d) => window.bench.load(d), msg.scene);
    else if (msg.cmd === "time") reply = { ms: await page.evaluate((n, s, w) => window.bench.time(n, s, w), msg.frames, msg.shadows, msg.whole !== false) };
    else if (msg.cmd === "image") reply = { rgba: await page.evaluate((m) => window.bench.image(m), msg.mode) };
    else if (msg.cmd === "quit") break;
    else reply = { error: `unknown command ${msg.cmd}` };
  } catch (e) {
    reply = { error: String(e) };
  }
  process.stdout.write(JSON.stringify(reply) + "\n");
}
await browser.close();
server.close();
