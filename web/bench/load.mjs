// The dashboard under load, in Debian's headless Chromium against the real daemon: a shot of
// FRAMES frames (default 500) with the job's grid open, and then either
//  - real: every frame receives ROUNDS more passes by upload, published as fast as the daemon can
//    (denoiser none; on this machine that is ~8-10 versions a second: fsync-bound), or
//  - RATE=50: the page's event stream comes from a relay that forwards every other request to the
//    daemon and emits `frame` events for the shot's frames at RATE a second for SECONDS (the
//    daemon here cannot publish 50 versions a second; the page's work per event is the same).
// Reports the event rate, how smooth the page stayed (animation-frame gaps, long tasks) and that
// every tile caught up. Usage: [RATE=50 SECONDS=20] node bench/load.mjs [FRAMES] [ROUNDS]
// (build/proden must exist; writes ../build/dashboard-artifacts/load*.json).
import { readFileSync, writeFileSync } from 'node:fs';
import { createServer, request as httpRequest } from 'node:http';
import { Daemon, artefact, cleanup, launchBrowser, sample, tempRoot, waitFor } from '../tests/browser/harness.mjs';

const FRAMES = Number(process.argv[2] ?? 500);
const ROUNDS = Number(process.argv[3] ?? 3);
const RATE = Number(process.env.RATE ?? 0);
const SECONDS = Number(process.env.SECONDS ?? 20);

/** A relay in front of the daemon whose /api/v1/events emits synthetic frame events at RATE/s. */
function relay(target, job, name, frames) {
  const version = new Map(frames.map((f) => [f.frame, f.version]));
  let id = Date.now() * 1000;
  const server = createServer((req, res) => {
    if (req.url.startsWith('/api/v1/events')) {
      res.writeHead(200, { 'Content-Type': 'text/event-stream', 'Cache-Control': 'no-cache' });
      res.write('retry: 2000\n\n');
      server.sent = 0;
      const timer = setInterval(() => {
        if (!server.go) return; // from when the page is ready and measuring
        const due = Math.floor(((Date.now() - server.go) / 1000) * RATE);
        while (server.sent < due && server.sent < RATE * SECONDS) {
          const f = frames[(server.sent * 7919) % frames.length].frame; // scattered over the grid
          const v = version.get(f) + 1;
          version.set(f, v);
          const data = { job, name, frame: f, version: v, passes: v, spp: 4 * v, new_passes: 1,
            estimated_mse: 0.01 / v, estimated_error: { mse: 0.01 / v, source: 'variance+sure' },
            render_mse: 0.03 / v, updated: new Date().toISOString() };
          res.write(`id: ${++id}\nevent: frame\ndata: ${JSON.stringify(data)}\n\n`);
          server.sent++;
        }
      }, 5);
      req.on('close', () => clearInterval(timer));
      return;
    }
    const u = new URL(target);
    const p = httpRequest({ host: u.hostname, port: u.port, path: req.url, method: req.method, headers: req.headers }, (r) => {
      res.writeHead(r.statusCode, r.headers);
      r.pipe(res);
    });
    req.pipe(p);
  });
  return new Promise((ok) => server.listen(0, '127.0.0.1', () => ok(server)));
}
const root = tempRoot();
const d = await new Daemon(root, { config: { worker_threads: Number(process.env.WORKERS ?? 16), limits: { sse_history: 4096 } } }).start();
const ctx = await launchBrowser(root);
try {
  const r = await d.request('POST', '/api/v1/jobs', {
    name: 'load',
    renderer: 'cycles',
    pipeline: { denoiser: 'none' },
    output: { dir: `${d.allowed}/load_out` },
  });
  const job = r.body.id;
  const passes = [0, 1, 2, 3, 4, 5, 6, 7].map((i) => readFileSync(sample('cornell', i)));
  const upload = (frame, k) =>
    fetch(`${d.url}/api/v1/jobs/${job}/frames/${frame}/passes/${String(k).padStart(2, '0')}`, {
      method: 'PUT',
      body: passes[k % 8],
    }).then((res) => {
      if (res.status !== 202) throw new Error(`upload ${frame}/${k}: ${res.status}`);
    });
  // Round 0 before the page opens: the grid starts with every frame.
  for (let f = 1; f <= FRAMES; f += 25) await Promise.all(Array.from({ length: Math.min(25, FRAMES - f + 1) }, (_, i) => upload(f + i, 0)));
  await waitFor(async () => (await d.frames(job)).size === FRAMES && [...(await d.frames(job)).values()].every((f) => f.version >= 1), 'round 0', 300000, 500);

  const page = await ctx.newPage();
  let base = d.url;
  let server = null;
  if (RATE > 0) {
    server = await relay(d.url, job, 'load', [...(await d.frames(job)).values()]);
    base = `http://127.0.0.1:${server.address().port}`;
  }
  await page.goto(`${base}/#/job/${job}`);
  await page.locator(`.tile[data-frame="${FRAMES}"]`).waitFor({ timeout: 60000 });
  await page.evaluate(() => {
    const w = window;
    w.__gaps = [];
    w.__long = [];
    let last = performance.now();
    const tick = (t) => {
      w.__gaps.push(t - last);
      last = t;
      if (!w.__stop) requestAnimationFrame(tick);
    };
    requestAnimationFrame(tick);
    new PerformanceObserver((l) => l.getEntries().forEach((e) => w.__long.push(e.duration))).observe({ entryTypes: ['longtask'] });
  });
  // The versions the tiles show, summed (each tile's badge follows its frame's events).
  const shown = () => page.evaluate(() => [...document.querySelectorAll('.tile')].reduce((a, t) => a + Number(t.dataset.version ?? 0), 0));
  const v0 = await shown();
  const t0 = Date.now();
  let expected;
  if (RATE > 0) {
    expected = v0 + RATE * SECONDS;
    server.go = Date.now();
    await waitFor(async () => server.sent >= RATE * SECONDS, 'the relay to send every event', (SECONDS + 30) * 1000, 100);
  } else {
    for (let k = 1; k <= ROUNDS; k++) {
      for (let f = 1; f <= FRAMES; f += 25) await Promise.all(Array.from({ length: Math.min(25, FRAMES - f + 1) }, (_, i) => upload(f + i, k)));
    }
    // Passes arriving while a frame runs coalesce into its next version: count what was published.
    const done = await waitFor(async () => {
      const fs = [...(await d.frames(job)).values()];
      return fs.every((f) => f.passes === ROUNDS + 1 && !f.pending) && fs;
    }, 'the daemon to take every round', 600000, 200);
    expected = done.reduce((a, f) => a + f.version, 0);
  }
  const tSource = Date.now();
  await waitFor(async () => (await shown()) === expected, 'every tile to show its last version', 60000, 200);
  const tPage = Date.now();
  const stats = await page.evaluate(() => {
    window.__stop = true;
    const g = [...window.__gaps].sort((a, b) => a - b);
    const q = (p) => g[Math.min(g.length - 1, Math.floor(p * g.length))];
    return {
      animation_frames: g.length,
      frame_gap_ms: { p50: q(0.5), p99: q(0.99), max: g[g.length - 1] },
      long_tasks: window.__long.length,
      longest_task_ms: Math.max(0, ...window.__long),
      tiles: document.querySelectorAll('.tile').length,
      dom_nodes: document.getElementsByTagName('*').length,
      measures_ms: Object.fromEntries(
        [...new Set(performance.getEntriesByType('measure').map((m) => m.name))].map((n) => {
          const d = performance.getEntriesByType('measure').filter((m) => m.name === n).map((m) => m.duration);
          return [n, { count: d.length, max: Math.max(...d), total: d.reduce((a, b) => a + b, 0) }];
        }),
      ),
    };
  });
  const updates = expected - v0;
  const out = {
    source: RATE > 0 ? `relay at ${RATE}/s` : 'daemon',
    frames: FRAMES,
    versions_received: updates,
    seconds: (tSource - t0) / 1000,
    updates_per_second: updates / ((tSource - t0) / 1000),
    page_caught_up_after_source_s: (tPage - tSource) / 1000,
    ...stats,
  };
  const tag = RATE > 0 ? `load_rate${RATE}` : 'load_daemon';
  await page.screenshot({ path: artefact(`${tag}.png`) });
  writeFileSync(artefact(`${tag}.json`), JSON.stringify(out, null, 2));
  console.log(JSON.stringify(out, null, 2));
  server?.close();
} finally {
  await ctx.close();
  await d.stop();
  cleanup(root);
}
