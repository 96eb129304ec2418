// The dashboard in Debian's headless Chromium against the real daemon on loopback, fed real passes
// (samples/renders) while the page is open: live thumbnails and charts without a reload, the wipe,
// pause/resume from the page, the farm integration's converged badge, recovery after a daemon
// restart, keyboard navigation, the token prompt. Screenshots go to ARTIFACT_DIR (docs/dashboard.md
// shows three of them).
import assert from 'node:assert/strict';
import { copyFileSync } from 'node:fs';
import { after, before, describe, it } from 'node:test';
import { Daemon, artefact, cleanup, launchBrowser, placePass, sample, tempRoot, waitFor } from './harness.mjs';

const FRAMES = [1, 2, 3, 4, 5, 6];
// Frame f shows cornell (odd) or textured_dof (even); its k-th pass is sample (f + k) % 8.
const scene = (f) => (f % 2 ? 'cornell' : 'textured_dof');
const src = (f, k) => sample(scene(f), (f + k) % 8);

describe('dashboard against the real daemon', () => {
  let root, d, ctx, page, job;
  const placed = new Map(FRAMES.map((f) => [f, 0]));
  const feed = (f) => {
    const k = placed.get(f);
    placePass(job.watch, String(k).padStart(2, '0'), f, src(f, k));
    placed.set(f, k + 1);
  };
  const tileVersion = (f) =>
    page.locator(`.tile[data-frame="${f}"] img`).getAttribute('data-version').then(Number);

  before(async () => {
    root = tempRoot();
    d = await new Daemon(root).start();
    job = await d.createJob('shot010');
    ctx = await launchBrowser(root);
    page = await ctx.newPage();
    page.on('pageerror', (e) => console.error('page error:', e.message));
  });

  after(async () => {
    await ctx?.close();
    const rc = await d?.stop();
    cleanup(root);
    assert.equal(rc, 0, 'the daemon stops cleanly');
  });

  it('serves the page from / with caching and gzip', async () => {
    const res = await fetch(d.url + '/', { headers: { 'Accept-Encoding': 'gzip' } });
    assert.equal(res.status, 200);
    assert.match(res.headers.get('content-type'), /^text\/html/);
    assert.equal(res.headers.get('cache-control'), 'no-cache');
    const html = await res.text(); // fetch decodes gzip
    const asset = /src="(\/assets\/[^"]+\.js)"/.exec(html)[1];
    const js = await fetch(d.url + asset, { headers: { 'Accept-Encoding': 'gzip' } });
    assert.equal(js.status, 200);
    assert.match(js.headers.get('content-type'), /^text\/javascript/);
    assert.match(js.headers.get('cache-control'), /immutable/);
    assert.equal(js.headers.get('content-encoding'), 'gzip');
    const again = await fetch(d.url + asset, { headers: { 'If-None-Match': js.headers.get('etag') } });
    assert.equal(again.status, 304);
  });

  it('shows the shot and updates a thumbnail on a new pass without a reload', async () => {
    for (const f of FRAMES) feed(f);
    await page.goto(`${d.url}/#/job/${job.id}`);
    await page.evaluate(() => (window.__sameDocument = true));
    await waitFor(async () => {
      for (const f of FRAMES) if ((await tileVersion(f).catch(() => 0)) < 1) return false;
      return true;
    }, 'every tile to show version 1');
    // The other tiles' elements must survive an update (no re-render of the grid).
    await page.evaluate(() => {
      window.__tile2 = document.querySelector('.tile[data-frame="2"]');
    });
    feed(1);
    await waitFor(async () => (await tileVersion(1)) >= 2, 'frame 1 thumbnail to show version 2');
    assert.equal(await page.evaluate(() => window.__sameDocument), true, 'no reload');
    assert.equal(
      await page.evaluate(() => window.__tile2 === document.querySelector('.tile[data-frame="2"]')),
      true,
      'tile 2 was patched, not rebuilt',
    );
    assert.match(await page.locator('.tile[data-frame="1"] .stats').textContent(), /v2 · 2 passes/);
    for (const f of [2, 3, 4, 1, 2, 3]) feed(f);
    // Passes that arrive while a frame runs coalesce into one version: wait for the daemon to take
    // every pass, then for every tile to show the daemon's version.
    const settled = await waitFor(async () => {
      const fs = await d.frames(job.id);
      return FRAMES.every((f) => fs.get(f)?.passes === placed.get(f) && !fs.get(f).pending) && fs;
    }, 'the daemon to take every pass');
    await waitFor(async () => {
      for (const f of FRAMES) if ((await tileVersion(f)) !== settled.get(f).version) return false;
      return (await page.locator('.tile .status.pending').count()) === 0;
    }, 'every tile to show its latest version');
    await page.screenshot({ path: artefact('live_shot.png'), fullPage: true });
  });

  it('moves between frames with the keyboard', async () => {
    await page.locator('.tile[tabindex="0"]').focus();
    const first = await page.evaluate(() => document.activeElement.dataset.frame);
    await page.keyboard.press('ArrowRight');
    const next = await page.evaluate(() => document.activeElement.dataset.frame);
    assert.equal(Number(next), Number(first) + 1);
  });

  it('updates the frame error chart on a new pass without a reload', async () => {
    await page.goto(`${d.url}/#/job/${job.id}/frame/1`);
    await page.evaluate(() => (window.__sameDocument = true));
    const points = () => page.locator('[data-chart="frame"]').getAttribute('data-points').then(Number);
    await waitFor(async () => (await points().catch(() => 0)) >= 2, 'the chart to show 2 versions');
    const before = await points();
    feed(1);
    await waitFor(async () => (await points()) === before + 1, 'the chart to gain a version');
    assert.equal(await page.evaluate(() => window.__sameDocument), true, 'no reload');
    const rows = await page.locator('table.history tbody tr').count();
    assert.equal(rows, before + 1, 'the version history lists every version');
    await page.locator('section:has(> [data-chart="frame"])').screenshot({ path: artefact('accuracy_chart.png') });
  });

  it('changes the pixels shown when the wipe slider moves', async () => {
    await page.selectOption('#layer-a', 'render');
    await page.selectOption('#layer-b', 'error');
    const stage = page.locator('.stage');
    await waitFor(async () => (await stage.getAttribute('data-layers')) === 'render,error', 'layers loaded');
    await page.locator('#wipe').fill('700');
    const at700 = await stage.screenshot();
    await page.locator('#wipe').fill('300');
    const at300 = await stage.screenshot();
    assert.notDeepEqual(at300, at700, 'the wipe changed the pixels');
    // Between 30 % and 70 % of the width the canvas now shows B (error), before it showed A.
    const sampleAt = () =>
      page.evaluate(() => {
        const c = document.querySelector('.stage canvas');
        const g = c.getContext('2d');
        return Array.from(g.getImageData(Math.round(c.width * 0.5), Math.round(c.height * 0.5), 1, 1).data);
      });
    const withB = await sampleAt();
    await page.locator('#wipe').fill('900');
    const withA = await sampleAt();
    assert.notDeepEqual(withA, withB, 'the centre pixel is A on one side of the wipe and B on the other');
    assert.ok(await page.locator('.legend[data-layer="error"]').isVisible(), 'the error layer has a legend');
    await page.locator('#wipe').fill('500');
    await page.locator('#zoom-in').click();
    await page.screenshot({ path: artefact('frame_wipe.png'), fullPage: true });
  });

  it('pauses and resumes the job from the page', async () => {
    await page.goto(`${d.url}/#/job/${job.id}`);
    const button = page.locator('.job-head button.pause');
    await button.waitFor();
    assert.equal(await button.getAttribute('data-action'), 'pause');
    await button.click();
    await waitFor(async () => (await d.request('GET', `/api/v1/jobs/${job.id}`)).body.state === 'paused', 'paused');
    await waitFor(async () => (await page.locator('.job-head button.pause').getAttribute('data-action')) === 'resume', 'the button to offer resume');
    assert.match(await page.locator('[data-field="state"]').textContent(), /paused/);
    const v = (await d.frames(job.id)).get(5).version;
    feed(5);
    await new Promise((r) => setTimeout(r, 2500)); // a paused job processes nothing
    assert.equal((await d.frames(job.id)).get(5).version, v, 'no new version while paused');
    await page.locator('.job-head button.pause').click();
    await waitFor(async () => (await d.request('GET', `/api/v1/jobs/${job.id}`)).body.state === 'active', 'resumed');
    await waitFor(async () => (await tileVersion(5)) > v, 'frame 5 to update after resuming');
  });

  it('badges a frame converged when the farm integration says so', async () => {
    // A job with a target every frame of 4 cornell passes meets with confidence (issue 13).
    const farm = await d.createJob('farmshot', { target: { relmse: 10 }, min_passes: 3 });
    for (let k = 0; k < 4; ++k) placePass(farm.watch, String(k).padStart(2, '0'), 1, sample('cornell', k));
    await waitFor(async () => (await d.frames(farm.id)).get(1)?.converged === true, 'the daemon to call frame 1 converged');
    await page.goto(`${d.url}/#/job/${farm.id}`);
    const badge = page.locator('.tile[data-frame="1"] .status');
    await waitFor(async () => /converged/.test((await badge.textContent().catch(() => '')) ?? ''), 'the tile to say converged');
    assert.match(await badge.getAttribute('class'), /\bconverged\b/);
    // Frames of the other job (no target) never say so.
    await page.goto(`${d.url}/#/job/${job.id}`);
    await page.locator('.tile[data-frame="1"]').waitFor();
    assert.equal(await page.locator('.tile .status.converged').count(), 0);
  });

  it('recovers after the daemon restarts', async () => {
    assert.equal(await d.stop(), 0);
    await waitFor(async () => (await page.evaluate(() => document.body.dataset.stream)) !== 'open', 'the page to notice');
    assert.match(await page.locator('#conn').textContent(), /reconnecting|connecting/);
    await d.start(); // same port, same state directory
    await waitFor(async () => (await page.evaluate(() => document.body.dataset.stream)) === 'open', 'the page to reconnect', 30000);
    const v = await tileVersion(6);
    feed(6);
    await waitFor(async () => (await tileVersion(6)) > v, 'frame 6 to update after the restart');
  });
});

describe('dashboard with a token', () => {
  it('asks for the token, then shows the jobs', async () => {
    const root = tempRoot();
    const d = await new Daemon(root, { token: 'dashboard-test-token-0123456789' }).start();
    const ctx = await launchBrowser(root);
    try {
      await d.createJob('secret');
      const anon = await fetch(d.url + '/api/v1/jobs');
      assert.equal(anon.status, 401, 'reads need the token by default');
      const page = await ctx.newPage();
      await page.goto(d.url + '/');
      await page.locator('#token-dialog[open]').waitFor();
      await page.fill('#token-input', 'dashboard-test-token-0123456789');
      await page.click('#token-dialog button[value="ok"]');
      await page.locator('tr[data-job] a', { hasText: 'secret' }).waitFor();
      await waitFor(async () => (await page.evaluate(() => document.body.dataset.stream)) === 'open', 'the stream to open with the token');
      await page.locator('[data-metric="workers"]').waitFor();
    } finally {
      await ctx.close();
      await d.stop();
      cleanup(root);
    }
  });
});
