// Browser-test harness: the real `proden serve` on a loopback port (as tests/service/harness.py
// starts it), passes placed into its watched directory the way a renderer writes them, and
// Debian's Chromium driven by playwright-core (never a downloaded browser).
import { spawn } from 'node:child_process';
import { copyFileSync, mkdirSync, mkdtempSync, renameSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { dirname, join, resolve } from 'node:path';
import { createInterface } from 'node:readline';
import { chromium } from 'playwright-core';

const here = dirname(new URL(import.meta.url).pathname);
export const BINARY = resolve(process.env.PRODEN_BINARY ?? join(here, '../../../build/proden'));
export const SAMPLES = resolve(process.env.PRODEN_SAMPLES_DIR ?? join(here, '../../../samples'));
export const ARTIFACTS = resolve(process.env.ARTIFACT_DIR ?? join(here, '../../../build/dashboard-artifacts'));
export const CHROMIUM = process.env.CHROMIUM ?? '/usr/bin/chromium';

export const sample = (scene, i) => join(SAMPLES, 'renders', scene, `pass_${String(i).padStart(2, '0')}.exr`);

export function tempRoot() {
  return mkdtempSync(join(tmpdir(), 'proden-dash-'));
}

export class Daemon {
  constructor(root, { token = null, config = {} } = {}) {
    this.root = root;
    this.allowed = join(root, 'allowed');
    this.state = join(root, 'state');
    this.token = token;
    this.config = { watch: { poll_interval_ms: 400, settle_ms: 250, tick_ms: 50 }, ...config };
    this.port = 0;
    mkdirSync(this.allowed, { recursive: true });
  }

  /** Starts the daemon (on the port it had before, after a restart). */
  async start() {
    const cfg = join(this.root, 'config.json');
    writeFileSync(cfg, JSON.stringify(this.config));
    const args = ['serve', '--port', String(this.port), '--state-dir', this.state, '--allow-root', this.allowed, '--config', cfg];
    if (this.token) {
      const tf = join(this.root, 'token');
      writeFileSync(tf, this.token + '\n', { mode: 0o600 });
      args.push('--token-file', tf);
    }
    this.proc = spawn(BINARY, args, { stdio: ['ignore', 'pipe', 'inherit'] });
    const lines = createInterface({ input: this.proc.stdout });
    this.url = await new Promise((ok, fail) => {
      const timer = setTimeout(() => fail(new Error('proden serve did not start in 20 s')), 20000);
      this.proc.once('exit', (code) => fail(new Error(`proden serve exited with ${code}`)));
      lines.on('line', (line) => {
        const m = /^listening on (http:\/\/[0-9.]+:(\d+))/.exec(line);
        if (m) {
          clearTimeout(timer);
          this.port = Number(m[2]);
          ok(m[1]);
        }
      });
    });
    return this;
  }

  async stop(signal = 'SIGTERM') {
    if (!this.proc || this.proc.exitCode !== null) return this.proc?.exitCode;
    const done = new Promise((ok) => this.proc.once('exit', (code, sig) => ok(code ?? sig)));
    this.proc.kill(signal);
    return done;
  }

  async request(method, path, body) {
    const headers = { 'Content-Type': 'application/json' };
    if (this.token) headers.Authorization = `Bearer ${this.token}`;
    const res = await fetch(this.url + path, { method, headers, body: body ? JSON.stringify(body) : undefined });
    const text = await res.text();
    return { status: res.status, body: text ? JSON.parse(text) : null };
  }

  async createJob(name, extra = {}) {
    const watch = join(this.allowed, `${name}_watch`);
    const r = await this.request('POST', '/api/v1/jobs', {
      name,
      renderer: 'cycles',
      watch: { dir: watch, pattern: 'pass_{pass}/beauty_####.exr' },
      output: { dir: join(this.allowed, `${name}_out`) },
      ...extra,
    });
    if (r.status !== 201) throw new Error(`job not created: ${JSON.stringify(r)}`);
    return { id: r.body.id, watch };
  }

  async frames(job) {
    const r = await this.request('GET', `/api/v1/jobs/${job}/frames`);
    return new Map(r.body.frames.map((f) => [f.frame, f]));
  }
}

/** Places a pass like a renderer does: temp name in the target directory, then rename. */
export function placePass(watchDir, pass, frame, src) {
  const dst = join(watchDir, `pass_${pass}`, `beauty_${String(frame).padStart(4, '0')}.exr`);
  mkdirSync(dirname(dst), { recursive: true });
  copyFileSync(src, dst + '.tmp');
  renameSync(dst + '.tmp', dst);
}

export async function waitFor(pred, what, timeoutMs = 30000, intervalMs = 100) {
  const deadline = Date.now() + timeoutMs;
  for (;;) {
    const v = await pred();
    if (v) return v;
    if (Date.now() > deadline) throw new Error(`timed out waiting for ${what}`);
    await new Promise((r) => setTimeout(r, intervalMs));
  }
}

/** Debian's Chromium, headless, with the flags that keep it off the (closed) network. */
export async function launchBrowser(root) {
  const userDataDir = join(root, 'chromium-profile');
  const context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: CHROMIUM,
    headless: true,
    viewport: { width: 1400, height: 1000 },
    args: [
      '--headless',
      '--no-sandbox',
      '--disable-gpu',
      '--disable-quic',
      '--no-first-run',
      '--disable-background-networking',
      '--disable-component-update',
      '--disable-sync',
    ],
  });
  return context;
}

export function artefact(name) {
  mkdirSync(ARTIFACTS, { recursive: true });
  return join(ARTIFACTS, name);
}

export function cleanup(root) {
  rmSync(root, { recursive: true, force: true });
}
