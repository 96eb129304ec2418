// One job: its state and pause/resume, throughput, quarantined files and errors, the shot's
// accuracy spread across frames, and the grid of frames with live thumbnails. 500 frames and 50
// updates a second: tiles are made once and patched in place, at most once per animation frame.
import { FrameBatcher } from '../batch';
import { ago, el, fixed, sci } from '../format';
import { jobSummary, shotSpread, throughput, type JobData } from '../store';
import { errorOf, type ErrorEvent, type FrameEvent, type FrameStatus, type JobEvent } from '../types';
import { ShotChart } from './charts';
import { stateChip } from './overview';
import type { Ctx, View } from './view';

export function pauseButton(ctx: Ctx, jobId: string): HTMLButtonElement {
  const d = ctx.store.jobs.get(jobId);
  const paused = d?.job.state === 'paused';
  const b = el('button', {
    type: 'button',
    class: 'pause',
    'data-action': paused ? 'resume' : 'pause',
    'aria-label': `${paused ? 'Resume' : 'Pause'} job ${d?.job.name ?? jobId}`,
    text: paused ? '▶ Resume' : '‖ Pause',
  });
  b.addEventListener('click', async () => {
    b.disabled = true;
    try {
      const job = await ctx.api.setPaused(jobId, !paused);
      ctx.store.setPaused(jobId, job.state === 'paused');
      ctx.announce(`Job ${job.name} ${job.state === 'paused' ? 'paused' : 'resumed'}`);
    } catch (e) {
      ctx.announce(`Could not ${paused ? 'resume' : 'pause'}: ${(e as Error).message}`);
    } finally {
      b.disabled = false;
      b.dispatchEvent(new CustomEvent('state-changed', { bubbles: true }));
    }
  });
  return b;
}

const THUMB = 160;
const THUMB_CONCURRENCY = 4;
const THUMB_MIN_INTERVAL_MS = 1000;

interface Tile {
  frame: number;
  a: HTMLAnchorElement;
  img: HTMLImageElement;
  label: HTMLElement;
  stats: HTMLElement;
  status: HTMLElement;
  visible: boolean;
  want: number; // version wanted
  have: number; // version shown
  loading: boolean;
  lastLoad: number;
  url: string | null;
}

/** Keeps tiles' thumbnails at their frame's latest version: visible tiles only, a few at a time. */
class ThumbLoader {
  private queue = new Set<Tile>();
  private active = 0;
  private timer: number | undefined;

  constructor(
    private ctx: Ctx,
    private jobId: string,
  ) {}

  want(t: Tile): void {
    if (t.visible && t.want > t.have) this.queue.add(t);
    this.pump();
  }

  private pump(): void {
    const now = performance.now();
    let wait = Infinity;
    for (const t of this.queue) {
      if (this.active >= THUMB_CONCURRENCY) break;
      if (!t.visible || t.want <= t.have) {
        this.queue.delete(t);
        continue;
      }
      if (t.loading) continue;
      const due = t.lastLoad + THUMB_MIN_INTERVAL_MS - now;
      if (due > 0) {
        wait = Math.min(wait, due);
        continue;
      }
      this.queue.delete(t);
      void this.load(t);
    }
    if (wait < Infinity && this.timer === undefined) {
      this.timer = window.setTimeout(() => {
        this.timer = undefined;
        this.pump();
      }, wait);
    }
  }

  private async load(t: Tile): Promise<void> {
    t.loading = true;
    t.lastLoad = performance.now();
    this.active++;
    try {
      const r = await this.ctx.api.image(this.jobId, t.frame, { layer: 'result', size: THUMB });
      const url = URL.createObjectURL(r.blob);
      await new Promise<void>((resolve) => {
        t.img.onload = t.img.onerror = () => resolve();
        t.img.src = url;
      });
      if (t.url) URL.revokeObjectURL(t.url);
      t.url = url;
      t.have = r.version ?? t.want;
      t.img.dataset.version = String(t.have);
      t.img.alt = `Frame ${t.frame}, version ${t.have}`;
    } catch {
      t.lastLoad = performance.now(); // retried after the interval
    } finally {
      t.loading = false;
      this.active--;
      if (t.want > t.have) this.queue.add(t);
      this.pump();
    }
  }

  dispose(): void {
    window.clearTimeout(this.timer);
    this.queue.clear();
  }
}

export class JobView implements View {
  readonly el = el('div', { class: 'job' });
  crumbs: { label: string; href: string }[] = [];
  private header = el('section', { class: 'panel job-head', 'aria-labelledby': 'job-h' });
  private problems = el('section', { class: 'panel problems', 'aria-labelledby': 'problems-h' });
  private grid = el('div', { class: 'grid', role: 'list', 'aria-label': 'Frames of the shot' });
  private chartHost = el('div', { class: 'chart', 'data-chart': 'shot' });
  private chart: ShotChart | null = null;
  private tiles = new Map<number, Tile>();
  private thumbs: ThumbLoader;
  private observer: IntersectionObserver;
  private batch: FrameBatcher<number>;
  private focused = -1;
  private tick: number;
  private slowTimer: number | undefined;
  private refreshing = false;

  constructor(
    private ctx: Ctx,
    private jobId: string,
  ) {
    this.thumbs = new ThumbLoader(ctx, jobId);
    this.batch = new FrameBatcher((frames) => this.flush(frames));
    this.observer = new IntersectionObserver(
      (entries) => {
        for (const e of entries) {
          const t = this.tiles.get(Number((e.target as HTMLElement).dataset.frame));
          if (!t) continue;
          t.visible = e.isIntersecting;
          if (t.visible) this.thumbs.want(t);
        }
      },
      { rootMargin: '200px' },
    );
    const shot = el(
      'section',
      { class: 'panel', 'aria-labelledby': 'shot-h' },
      el('h2', { id: 'shot-h', text: 'Accuracy over samples' }),
      this.chartHost,
    );
    const gridPanel = el(
      'section',
      { class: 'panel', 'aria-labelledby': 'grid-h' },
      el('h2', { id: 'grid-h', text: 'Frames' }),
      el('p', { class: 'hint', text: 'Arrow keys move between frames; Enter opens one.' }),
      this.grid,
    );
    this.el.append(this.header, el('div', { class: 'two' }, shot, this.problems), gridPanel);
    this.grid.addEventListener('keydown', (e) => this.key(e));
    this.el.addEventListener('state-changed', () => this.renderHeader());
    this.tick = window.setInterval(() => {
      this.renderHeader();
      void this.refreshPending();
    }, 5000);
  }

  /**
   * Asks the daemon again about frames shown as pending. A frame stays pending (its worker busy)
   * for a moment after its version's event, and no event says when that ends: a snapshot taken in
   * that moment would leave the tile pending for good.
   */
  private async refreshPending(): Promise<void> {
    const d = this.data;
    if (!d || this.refreshing || ![...d.frames.values()].some((f) => f.pending)) return;
    this.refreshing = true;
    try {
      for (const f of this.ctx.store.setFrames(this.jobId, await this.ctx.api.frames(this.jobId))) this.batch.mark(f);
    } catch {
      // the next tick asks again; the connection indicator shows a daemon that is away
    } finally {
      this.refreshing = false;
    }
  }

  private get data(): JobData | undefined {
    return this.ctx.store.jobs.get(this.jobId);
  }

  async resync(): Promise<void> {
    const { api, store } = this.ctx;
    store.setJobs(await api.jobs());
    const [frames, hist, q] = await Promise.all([
      api.frames(this.jobId),
      api.jobHistory(this.jobId),
      api.quarantine(this.jobId),
    ]);
    const changed = store.setFrames(this.jobId, frames);
    store.setHistory(this.jobId, hist);
    const d = this.data;
    if (!d) return;
    d.quarantined = q;
    this.crumbs = [{ label: d.job.name, href: `#/job/${d.job.id}` }];
    for (const f of changed) this.batch.mark(f);
    for (const f of d.frames.keys()) if (!this.tiles.has(f)) this.batch.mark(f);
    this.renderHeader();
    this.renderProblems();
    this.renderChart();
  }

  private renderHeader(): void {
    const d = this.data;
    if (!d) return;
    const s = jobSummary(d);
    const t = throughput(d.versions, Date.now(), 5 * 60_000);
    this.header.replaceChildren(
      el('h1', { id: 'job-h', text: `Job ${d.job.name}` }),
      el(
        'dl',
        { class: 'kv row' },
        el('dt', { text: 'State' }),
        el('dd', { 'data-field': 'state' }, stateChip(d.job.state)),
        el('dt', { text: 'Frames' }),
        el('dd', { text: `${s.published} published of ${s.frames}${s.pending ? `, ${s.pending} pending` : ''}` }),
        el('dt', { text: 'Converged' }),
        el('dd', { text: String(s.converged) }),
        el('dt', { text: 'Passes' }),
        el('dd', { 'data-field': 'passes', text: String(s.passes) }),
        el('dt', { text: 'Throughput' }),
        el('dd', { text: `${fixed(t.passesPerMin)} passes/min, ${fixed(t.updatesPerMin)} versions/min` }),
        el('dt', { text: 'Pipeline' }),
        el('dd', { text: `${d.job.pipeline?.denoiser ?? 'auto'} / ${d.job.pipeline?.mixer ?? 'auto'}` }),
      ),
      pauseButton(this.ctx, d.job.id),
    );
  }

  private renderProblems(): void {
    const d = this.data;
    if (!d) return;
    const q = d.quarantined;
    const recent = d.errors.filter((e) => !e.quarantined).slice(-20);
    this.problems.replaceChildren(
      el('h2', { id: 'problems-h', text: `Errors and quarantined files (${q.length + recent.length})` }),
      q.length + recent.length === 0
        ? el('p', { text: '✓ None.' })
        : el(
            'ul',
            { class: 'problems-list' },
            ...q.map((r) =>
              el(
                'li',
                {},
                el('strong', { text: `⚠ quarantined (${r.kind})` }),
                ` frame ${r.frame}, pass ${r.pass}: ${r.message} `,
                el('code', { text: r.path }),
              ),
            ),
            ...recent.map((r) =>
              el('li', {}, el('strong', { text: `⚠ ${r.kind}` }), ` frame ${r.frame}${r.pass ? `, pass ${r.pass}` : ''}: ${r.message}`),
            ),
          ),
    );
  }

  private renderChart(): void {
    const d = this.data;
    if (!d) return;
    if (!this.chart) this.chart = new ShotChart(this.chartHost);
    this.chart.update(shotSpread(d.versions));
  }

  /** Patches the tiles of `frames` (creating new ones in frame order): the only DOM writes. */
  private flush(frames: Set<number>): void {
    const d = this.data;
    if (!d) return;
    const t0 = performance.now();
    for (const n of frames) {
      const f = d.frames.get(n);
      let t = this.tiles.get(n);
      if (!f) {
        if (t) this.removeTile(t);
        continue;
      }
      if (!t) t = this.addTile(n);
      this.patch(t, f);
    }
    if (this.focused < 0 && this.tiles.size) {
      const first = this.ordered()[0];
      first.a.tabIndex = 0;
      this.focused = first.frame;
    }
    performance.measure('grid-flush', { start: t0 }); // read by web/bench/load.mjs
    this.slow();
  }

  /** The header and the chart summarise all frames: redrawn at most twice a second. */
  private slow(): void {
    if (this.slowTimer !== undefined) return;
    this.slowTimer = window.setTimeout(() => {
      this.slowTimer = undefined;
      const t0 = performance.now();
      this.renderHeader();
      performance.measure('job-header', { start: t0 });
      const t1 = performance.now();
      this.renderChart();
      performance.measure('shot-chart', { start: t1 });
    }, 500);
  }

  private ordered(): Tile[] {
    return [...this.tiles.values()].sort((a, b) => a.frame - b.frame);
  }

  private addTile(n: number): Tile {
    const a = el('a', { class: 'tile', href: `#/job/${this.jobId}/frame/${n}`, role: 'listitem', tabindex: '-1' });
    a.dataset.frame = String(n);
    const img = el('img', { alt: `Frame ${n}, no version yet`, width: String(THUMB), height: String(THUMB), decoding: 'async' });
    img.dataset.version = '0';
    const label = el('span', { class: 'frame-no', text: `#${n}` });
    const status = el('span', { class: 'status' });
    const stats = el('span', { class: 'stats' });
    a.append(el('span', { class: 'thumb' }, img, label, status), stats);
    const t: Tile = { frame: n, a, img, label, stats, status, visible: false, want: 0, have: 0, loading: false, lastLoad: -Infinity, url: null };
    // keep frame order: before the first tile with a larger number
    let before: Tile | undefined;
    for (const o of this.tiles.values()) if (o.frame > n && (!before || o.frame < before.frame)) before = o;
    this.grid.insertBefore(a, before ? before.a : null);
    this.tiles.set(n, t);
    this.observer.observe(a);
    return t;
  }

  private removeTile(t: Tile): void {
    this.observer.unobserve(t.a);
    t.a.remove();
    if (t.url) URL.revokeObjectURL(t.url);
    this.tiles.delete(t.frame);
    if (this.focused === t.frame) this.focused = -1;
  }

  private patch(t: Tile, f: FrameStatus): void {
    const err = errorOf(f);
    const extra = f.estimated_error?.equivalent_spp ? ` · ≈${fixed(f.estimated_error.equivalent_spp, 0)} spp eq.` : '';
    t.stats.textContent = `v${f.version} · ${f.passes} pass${f.passes === 1 ? '' : 'es'} · ${fixed(f.spp, 0)} spp · err ${sci(err)}${extra}`;
    t.a.dataset.version = String(f.version);
    const st = f.converged ? '✓ converged' : f.pending ? '… pending' : f.version === 0 ? '○ waiting' : '';
    t.status.textContent = st;
    t.status.className = `status${f.converged ? ' converged' : f.pending ? ' pending' : ''}`;
    t.a.setAttribute(
      'aria-label',
      `Frame ${f.frame}: version ${f.version}, ${f.passes} passes, ${fixed(f.spp, 0)} spp, estimated error ${sci(err)}${st ? ', ' + st.slice(2) : ''}, updated ${ago(f.updated)}`,
    );
    t.want = Math.max(t.want, f.version);
    this.thumbs.want(t);
  }

  private key(e: KeyboardEvent): void {
    const order = this.ordered();
    const i = order.findIndex((t) => t.frame === this.focused);
    if (i < 0) return;
    const cols = Math.max(1, Math.round(this.grid.clientWidth / (order[0].a.offsetWidth || 1)));
    const step: Record<string, number> = { ArrowRight: 1, ArrowLeft: -1, ArrowDown: cols, ArrowUp: -cols, Home: -i, End: order.length - 1 - i };
    const s = step[e.key];
    if (s === undefined) return;
    e.preventDefault();
    const j = Math.min(order.length - 1, Math.max(0, i + s));
    order[i].a.tabIndex = -1;
    order[j].a.tabIndex = 0;
    order[j].a.focus();
    this.focused = order[j].frame;
  }

  onFrame(e: FrameEvent): void {
    if (e.job !== this.jobId) return;
    this.batch.mark(e.frame);
  }

  onJob(e: JobEvent): void {
    if (e.job === this.jobId) void this.resync();
  }

  onError(e: ErrorEvent): void {
    if (e.job === this.jobId) {
      if (e.quarantined) void this.ctx.api.quarantine(this.jobId).then((q) => {
        const d = this.data;
        if (d) d.quarantined = q;
        this.renderProblems();
      });
      else this.renderProblems();
    }
  }

  destroy(): void {
    this.observer.disconnect();
    this.thumbs.dispose();
    this.chart?.destroy();
    window.clearInterval(this.tick);
    window.clearTimeout(this.slowTimer);
    for (const t of this.tiles.values()) if (t.url) URL.revokeObjectURL(t.url);
  }

  /** For the tests and the benchmark: tiles made so far. */
  get tileCount(): number {
    return this.tiles.size;
  }
}
