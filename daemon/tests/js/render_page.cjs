#!/usr/bin/env node
// Renders a live page in headless Chromium and waits until it shows what is asked, through the
// DevTools protocol (a page fed over a WebSocket fills in after it loads, which --dump-dom and
// --screenshot do not wait for). Prints the page's HTML on stdout once
// `document.querySelectorAll(SELECTOR).length > 0` (or fails after 90 s), and saves a
// screenshot of the 1280x800 window.
//
// Usage: NODE_PATH=<npm dir>/node_modules node render_page.cjs CHROMIUM URL SELECTOR SHOT.png PROFILE
// (PROFILE: an empty directory for Chromium's profile, which the caller removes).

"use strict";
const { spawn } = require("child_process");
const fs = require("fs");
const WebSocket = require("ws");

const [bin, url, selector, shot, profile] = process.argv.slice(2);
const LIMIT_MS = 90000;
const browser = spawn(bin, [
  "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
  "--disable-component-update", "--disable-sync", "--no-first-run",
  "--window-size=1280,800", "--remote-debugging-port=0", `--user-data-dir=${profile}`,
  "about:blank",
], { stdio: ["ignore", "ignore", "pipe"] });

function fail(msg) {
  process.stderr.write(`render_page: ${msg}\n`);
  browser.kill("SIGKILL");
  process.exit(1);
}
// What the page reported (exceptions, console), and its text, say why it showed nothing.
const seen = [];
let pageText = async () => "";
setTimeout(async () => {
  const text = await pageText().catch((e) => String(e));
  fail(`nothing matched ${selector} within ${LIMIT_MS} ms; page text:\n${text}\n${seen.join("\n")}`);
}, LIMIT_MS).unref();

function devtoolsUrl() {
  return new Promise((resolve) => {
    let text = "";
    browser.stderr.on("data", (d) => {
      text += d.toString();
      const m = text.match(/DevTools listening on (ws:\/\/\S+)/);
      if (m) resolve(m[1]);
    });
    browser.on("exit", (code) => fail(`chromium exited (${code}): ${text}`));
  });
}

async function main() {
  const ws = new WebSocket(await devtoolsUrl());
  await new Promise((resolve, reject) => { ws.on("open", resolve); ws.on("error", reject); });
  let next = 0;
  const pending = new Map();
  ws.on("message", (raw) => {
    const m = JSON.parse(raw.toString());
    if (m.method === "Runtime.exceptionThrown") seen.push(JSON.stringify(m.params.exceptionDetails));
    if (m.method === "Runtime.consoleAPICalled") seen.push(JSON.stringify(m.params.args));
    const p = pending.get(m.id);
    if (!p) return;
    pending.delete(m.id);
    if (m.error) p.reject(new Error(JSON.stringify(m.error)));
    else p.resolve(m.result);
  });
  const call = (method, params = {}, sessionId) => new Promise((resolve, reject) => {
    const id = ++next;
    pending.set(id, { resolve, reject });
    ws.send(JSON.stringify({ id, method, params, sessionId }));
  });
  const { targetId } = await call("Target.createTarget", { url });
  const { sessionId } = await call("Target.attachToTarget", { targetId, flatten: true });
  const evaluate = async (expression) =>
    (await call("Runtime.evaluate", { expression, returnByValue: true }, sessionId)).result.value;
  await call("Runtime.enable", {}, sessionId);
  pageText = () => evaluate("document.body.innerText");
  // The condition and the HTML in one evaluation: the page's scripts cannot run between them,
  // so the HTML returned is one the selector matches (a later read could see the next dwell).
  const query = `document.querySelectorAll(${JSON.stringify(selector)}).length > 0 ? document.documentElement.outerHTML : null`;
  let html = null;
  while ((html = await evaluate(query)) === null) {
    await new Promise((r) => setTimeout(r, 200)); // poll the condition
  }
  const { data } = await call("Page.captureScreenshot", { format: "png" }, sessionId);
  fs.writeFileSync(shot, Buffer.from(data, "base64"));
  await call("Browser.close").catch(() => {});
  browser.removeAllListeners("exit");
  browser.kill("SIGKILL");
  // Exit once the pipe has it all (stdout to a pipe is asynchronous in node).
  process.stdout.write(html, () => process.exit(0));
}
main().catch((e) => fail(e.stack || String(e)));
