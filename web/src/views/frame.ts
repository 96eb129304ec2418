// One frame: a viewer with exposure, an A/B wipe between render, denoised, result, alpha and the
// errors (colour-mapped by the daemon, with a legend), zoom down to pixels, the frame's accuracy
// over time against the plain render's, and its version history.
import type { ImageRendition } from '../api';
import { FrameBatcher } from '../batch';
import { mergeFrameSnapshot } from '../store';
import { decades, el, fixed, sci } from '../format';
import { errorOf, type ColourMaps, type EstimatedError, type FrameEvent, type FrameStatus, type Version } from '../types';
import { FrameChart, type FrameAxis } from './charts';
import type { Ctx, View } from './view';

export const LAYERS: { id: string; label: string }[] = [
  { id: 'render', label: 'render (plain Monte Carlo)' },
  { id: 'denoised', label: 'denoised' },
  { id: 'result', label: 'result (published)' },
  { id: 'alpha', label: 'alpha (mixing weight)' },
  { id: 'error', label: 'error of the result (estimated)' },
  { id: 'variance', label: 'error of the render (Var[x])' },
  { id: 'sure', label: 'error of the denoised (SURE)' },
  { id: 'mixvariance', label: 'Var[x] as the mixer reads it' },
];

interface Shown {
  bitmap: ImageBitmap;
  r: ImageRendition;
}

export class FrameView implements View {
  readonly el = el('div', { class: 'frame' });
  crumbs: { label: string; href: string }[] = [];
  private status: FrameStatus | null = null;
  private versions: Version[] = [];
  private canvas = el('canvas', { class: 'viewer-canvas', 'aria-hidden': 'true' });
  private stage = el('div', {
    class: 'stage',
    tabindex: '0',
    role: 'img',
    'aria-label': 'Frame viewer. Arrow keys pan, + and - zoom, 0 fits, 1 shows pixels 1:1, [ and ] move the wipe.',
  });
  private selA = this.select('layer-a', 'render');
  private selB = this.select('layer-b', 'result');
  private wipe = el('input', { type: 'range', min: '0', max: '1000', value: '500', id: 'wipe', 'aria-label': 'Wipe position between A and B' });
  private exposure = el('input', { type: 'range', min: '-8', max: '8', step: '0.25', value: '0', id: 'exposure', 'aria-label': 'Exposure (EV)' });
  private exposureOut = el('output', { for: 'exposure', text: '+0.00 EV' });
  private zoomOut = el('output', { class: 'zoom-level', text: 'fit' });
  private legends = el('div', { class: 'legends' });
  private labelA = el('span', { class: 'tag tag-a' });
  private labelB = el('span', { class: 'tag tag-b' });
  private info = el('dl', { class: 'kv' });
  private chartHost = el('div', { class: 'chart', 'data-chart': 'frame' });
  private chart: FrameChart | null = null;
  private axis: FrameAxis = 'spp';
  private historyBody = el('tbody');
  private a: Shown | null = null;
  private b: Shown | null = null;
  private scale = 0; // 0 = fit
  private panX = 0;
  private panY = 0;
  private loadSeq = 0;
  private exposureTimer: number | undefined;
  private batch = new FrameBatcher<number>(() => void this.refresh());
  private resizeObs: ResizeObserver;
  private origin = 0;
  private pinned: number | null = null; // an older version shown instead of the latest
  private tick: number;
  private refreshing = false;

  constructor(
    private ctx: Ctx,
    private jobId: string,
    private frameNo: number,
  ) {
    const controls = el(
      'div',
      { class: 'controls' },
      el('label', {}, 'A ', this.selA),
      el('label', {}, 'B ', this.selB),
      el('label', { class: 'grow' }, 'Wipe ', this.wipe),
      el('label', {}, 'Exposure ', this.exposure, this.exposureOut),
      el(
        'span',
        { class: 'zoom', role: 'group', 'aria-label': 'Zoom' },
        this.button('Fit', 'zoom-fit', () => this.setScale(0)),
        this.button('1:1', 'zoom-1', () => this.setScale(1)),
        this.button('−', 'zoom-out', () => this.zoomBy(0.5), 'Zoom out'),
        this.button('+', 'zoom-in', () => this.zoomBy(2), 'Zoom in'),
        this.zoomOut,
      ),
    );
    this.stage.append(this.canvas, this.labelA, this.labelB);
    const viewer = el(
      'section',
      { class: 'panel viewer', 'aria-labelledby': 'viewer-h' },
      el('h1', { id: 'viewer-h', text: `Frame ${frameNo}` }),
      controls,
      this.stage,
      this.legends,
    );
    const axisSel = el(
      'fieldset',
      { class: 'axis' },
      el('legend', { text: 'x axis' }),
      this.radio('spp', 'samples per pixel', true),
      this.radio('time', 'wall time', false),
    );
    const side = el(
      'div',
      { class: 'side' },
      el('section', { class: 'panel', 'aria-labelledby': 'info-h' }, el('h2', { id: 'info-h', text: 'Now' }), this.info),
      el(
        'section',
        { class: 'panel', 'aria-labelledby': 'acc-h' },
        el('h2', { id: 'acc-h', text: 'Accuracy over time' }),
        axisSel,
        this.chartHost,
      ),
    );
    const history = el(
      'section',
      { class: 'panel', 'aria-labelledby': 'hist-h' },
      el('h2', { id: 'hist-h', text: 'Version history' }),
      el(
        'table',
        { class: 'history' },
        el(
          'thead',
          {},
          el(
            'tr',
            {},
            ...['', 'version', 'published', 'passes', 'spp', 'est. error (result)', 'render (mean Var[x])', 'render / result'].map((t) =>
              el('th', { scope: 'col', text: t }),
            ),
          ),
        ),
        this.historyBody,
      ),
    );
    this.el.append(el('div', { class: 'frame-top' }, viewer, side), history);

    this.selA.addEventListener('change', () => void this.loadImages());
    this.selB.addEventListener('change', () => void this.loadImages());
    this.wipe.addEventListener('input', () => this.draw());
    this.exposure.addEventListener('input', () => {
      const ev = Number(this.exposure.value);
      this.exposureOut.textContent = `${ev >= 0 ? '+' : ''}${ev.toFixed(2)} EV`;
      window.clearTimeout(this.exposureTimer);
      this.exposureTimer = window.setTimeout(() => void this.loadImages(), 120);
    });
    this.stage.addEventListener('keydown', (e) => this.key(e));
    this.stage.addEventListener('wheel', (e) => {
      e.preventDefault();
      this.zoomBy(e.deltaY < 0 ? 1.25 : 0.8);
    }, { passive: false });
    this.dragToPan();
    this.resizeObs = new ResizeObserver(() => this.draw());
    this.resizeObs.observe(this.stage);
    this.tick = window.setInterval(() => void this.refreshPending(), 5000);
  }

  private select(id: string, value: string): HTMLSelectElement {
    const s = el('select', { id, 'aria-label': id === 'layer-a' ? 'Layer A (left of the wipe)' : 'Layer B (right of the wipe)' });
    for (const l of LAYERS) s.append(el('option', { value: l.id, text: l.label }));
    s.value = value;
    return s;
  }

  private button(text: string, id: string, fn: () => void, label?: string): HTMLButtonElement {
    const b = el('button', { type: 'button', id, text, ...(label ? { 'aria-label': label } : {}) });
    b.addEventListener('click', fn);
    return b;
  }

  private radio(value: FrameAxis, label: string, checked: boolean): HTMLLabelElement {
    const r = el('input', { type: 'radio', name: 'axis', value });
    r.checked = checked;
    r.addEventListener('change', () => {
      this.axis = value;
      this.renderChart();
    });
    return el('label', {}, r, ' ' + label);
  }

  async resync(): Promise<void> {
    const { api, store } = this.ctx;
    const [jobs, status, versions] = await Promise.all([
      api.jobs(),
      api.frame(this.jobId, this.frameNo),
      api.history(this.jobId, this.frameNo),
    ]);
    store.setJobs(jobs);
    const job = store.jobs.get(this.jobId)?.job;
    this.origin = job ? Date.parse(job.created) : 0;
    this.crumbs = [
      { label: job?.name ?? this.jobId, href: `#/job/${this.jobId}` },
      { label: `frame ${this.frameNo}`, href: `#/job/${this.jobId}/frame/${this.frameNo}` },
    ];
    const d = store.jobs.get(this.jobId);
    const merged = mergeFrameSnapshot(status, versions, d?.frames.get(this.frameNo), d?.versions.get(this.frameNo));
    this.status = merged.status;
    this.versions = merged.versions;
    this.renderInfo();
    this.renderChart();
    this.renderHistory();
    await this.loadImages();
  }

  private async refresh(): Promise<void> {
    this.renderInfo();
    this.renderChart();
    this.renderHistory();
    if (this.pinned === null) await this.loadImages(); // a pinned older version stays on screen
  }

  onFrame(e: FrameEvent): void {
    if (e.job !== this.jobId || e.frame !== this.frameNo) return;
    const d = this.ctx.store.jobs.get(this.jobId);
    const st = d?.frames.get(this.frameNo);
    if (st) this.status = { ...this.status, ...st };
    this.versions = [...(d?.versions.get(this.frameNo) ?? this.versions)];
    this.batch.mark(e.version);
  }

  private renderInfo(): void {
    const s = this.status;
    if (!s) return;
    const last = this.versions[this.versions.length - 1];
    const ee: Partial<EstimatedError> = s.estimated_error ?? {};
    const rows: [string, string, string][] = [
      ['Version', String(s.version), 'version'],
      ['Passes', String(s.passes), 'passes'],
      ['spp', fixed(s.spp, 0), 'spp'],
      ['Est. error (MSE)', sci(errorOf(s)), 'error'],
      ['Render error (mean Var[x])', sci(last?.render_mse), 'render'],
    ];
    const interval = (lo: unknown, hi: unknown, f: (x: number) => string) =>
      typeof lo === 'number' || typeof hi === 'number'
        ? ` (${typeof lo === 'number' ? f(lo) : '–'} … ${typeof hi === 'number' ? f(hi) : '∞'})`
        : '';
    if (typeof ee.mse_low === 'number' || typeof ee.mse_high === 'number') {
      rows[3][1] += interval(ee.mse_low, ee.mse_high, (x) => sci(x));
    }
    if (typeof ee.relmse === 'number') {
      rows.push(['Est. relMSE', sci(ee.relmse) + interval(ee.relmse_low, ee.relmse_high, (x) => sci(x)), 'relmse']);
    }
    if (typeof ee.equivalent_spp === 'number') {
      rows.push([
        'Equivalent spp',
        fixed(ee.equivalent_spp, 0) + interval(ee.equivalent_spp_low, ee.equivalent_spp_high, (x) => fixed(x, 0)),
        'eqspp',
      ]);
    }
    if (s.converged !== undefined) rows.push(['Converged', s.converged ? '✓ yes' : '✗ not yet', 'converged']);
    rows.push(['State', s.pending ? '… processing' : 'idle', 'pending']);
    this.info.replaceChildren(...rows.flatMap(([k, v, f]) => [el('dt', { text: k }), el('dd', { 'data-field': f, text: v })]));
  }

  private renderChart(): void {
    if (!this.chart) this.chart = new FrameChart(this.chartHost);
    this.chart.update(this.versions, this.axis, this.origin);
  }

  /** Shows version `v` in the viewer (null: follow the latest). */
  private pin(v: number | null): void {
    this.pinned = v === this.status?.version ? null : v;
    this.renderHistory();
    void this.loadImages();
  }

  private renderHistory(): void {
    const kept = new Set(this.status?.versions ?? []);
    const rows = [...this.versions].reverse().map((v) => {
      const e = errorOf(v);
      const shown = (this.pinned ?? this.status?.version) === v.version;
      let action: HTMLElement = el('span', { text: shown ? '◉ shown' : '' });
      if (!shown && (kept.has(v.version) || v.version === this.status?.version)) {
        const b = el('button', { type: 'button', text: 'view', 'aria-label': `View version ${v.version}` });
        b.addEventListener('click', () => this.pin(v.version));
        action = b;
      }
      return el(
        'tr',
        shown ? { 'aria-current': 'true' } : {},
        el('td', {}, action),
        el('td', { class: 'num', text: String(v.version) }),
        el('td', { text: new Date(v.updated).toLocaleTimeString() }),
        el('td', { class: 'num', text: String(v.passes) }),
        el('td', { class: 'num', text: fixed(v.spp, 0) }),
        el('td', { class: 'num', text: sci(e) }),
        el('td', { class: 'num', text: sci(v.render_mse) }),
        el('td', { class: 'num', text: v.render_mse && e > 0 ? `${fixed(v.render_mse / e, 1)}×` : '–' }),
      );
    });
    this.historyBody.replaceChildren(...rows);
  }

  /** Fetches the two layers (B on A's log range when both are errors, so colours compare). */
  private async loadImages(): Promise<void> {
    const seq = ++this.loadSeq;
    if (!this.status || this.status.version === 0) return;
    const exposure = Number(this.exposure.value);
    const version = this.pinned ?? undefined;
    const get = (layer: string, range?: [number, number]) =>
      this.ctx.api.image(this.jobId, this.frameNo, { layer, exposure, range, version });
    try {
      const maps = await this.ctx.colourMaps();
      const ra = await get(this.selA.value);
      const log = (l: string) => maps.layers[l]?.scale === 'log';
      const shareRange = log(this.selA.value) && log(this.selB.value) && ra.range !== null;
      const rb = await get(this.selB.value, shareRange ? (ra.range as [number, number]) : undefined);
      const [ba, bb] = await Promise.all([createImageBitmap(ra.blob), createImageBitmap(rb.blob)]);
      if (seq !== this.loadSeq) return;
      this.a = { bitmap: ba, r: ra };
      this.b = { bitmap: bb, r: rb };
      this.stage.dataset.version = String(Math.min(ra.version ?? 0, rb.version ?? 0));
      this.stage.dataset.layers = `${this.selA.value},${this.selB.value}`;
      const which = this.pinned ? ` (v${this.pinned})` : '';
      this.labelA.textContent = `A: ${this.selA.value}${which}`;
      this.labelB.textContent = `B: ${this.selB.value}${which}`;
      this.renderLegends(maps);
      this.draw();
    } catch (e) {
      if (seq === this.loadSeq) this.ctx.announce(`Image not available: ${(e as Error).message}`);
    }
  }

  private renderLegends(maps: ColourMaps): void {
    const items: HTMLElement[] = [];
    const seen = new Set<string>();
    for (const [tag, s, layer] of [['A', this.a, this.selA.value], ['B', this.b, this.selB.value]] as const) {
      if (!s || !s.r.colormap || !s.r.range) continue;
      const key = `${layer}:${s.r.range.join(',')}`;
      if (seen.has(key)) continue;
      seen.add(key);
      const stops = maps.colormaps[s.r.colormap] ?? [];
      const [lo, hi] = s.r.range;
      const logScale = s.r.scale === 'log';
      const ticks = logScale ? decades(lo, hi) : [lo, (lo + hi) / 2, hi];
      const pos = (v: number) => (logScale ? Math.log(v / lo) / Math.log(hi / lo) : (v - lo) / (hi - lo));
      const bar = el('div', { class: 'legend-bar', 'aria-hidden': 'true' });
      bar.style.background = `linear-gradient(to right, ${stops.join(', ')})`;
      const tickRow = el('div', { class: 'legend-ticks', 'aria-hidden': 'true' });
      for (const t of ticks) {
        const s2 = el('span', { text: logScale ? sci(t, 1) : fixed(t, 1) });
        s2.style.left = `${(pos(t) * 100).toFixed(2)}%`;
        tickRow.append(s2);
      }
      const desc = logScale
        ? `${layer}: log scale, ${sci(lo, 1)} (and below, incl. ≤ 0) to ${sci(hi, 1)} and above`
        : `${layer}: linear, ${fixed(lo, 1)} to ${fixed(hi, 1)}`;
      items.push(
        el('figure', { class: 'legend', 'data-layer': layer }, el('figcaption', { text: `${tag} — ${desc} (${s.r.colormap})` }), bar, tickRow),
      );
    }
    this.legends.replaceChildren(...items);
  }

  // ---- drawing, zoom and pan ----

  private fitScale(): number {
    if (!this.a) return 1;
    const w = this.stage.clientWidth;
    const h = this.stage.clientHeight;
    return Math.min(w / this.a.bitmap.width, h / this.a.bitmap.height);
  }

  private setScale(s: number): void {
    this.scale = s;
    this.panX = 0;
    this.panY = 0;
    this.draw();
  }

  private zoomBy(f: number): void {
    const cur = this.scale || this.fitScale();
    this.scale = Math.min(64, Math.max(0.05, cur * f));
    this.draw();
  }

  private draw(): void {
    const dpr = window.devicePixelRatio || 1;
    const w = this.stage.clientWidth;
    const h = this.stage.clientHeight;
    if (this.canvas.width !== Math.round(w * dpr) || this.canvas.height !== Math.round(h * dpr)) {
      this.canvas.width = Math.round(w * dpr);
      this.canvas.height = Math.round(h * dpr);
    }
    const g = this.canvas.getContext('2d');
    if (!g || !this.a || !this.b) return;
    const s = this.scale || this.fitScale();
    this.zoomOut.textContent = this.scale ? `${(s * 100).toFixed(0)} %` : `fit (${(s * 100).toFixed(0)} %)`;
    const iw = this.a.bitmap.width;
    const ih = this.a.bitmap.height;
    const ox = (w - iw * s) / 2 + this.panX;
    const oy = (h - ih * s) / 2 + this.panY;
    g.setTransform(1, 0, 0, 1, 0, 0);
    g.fillStyle = '#0d1117';
    g.fillRect(0, 0, this.canvas.width, this.canvas.height);
    g.imageSmoothingEnabled = s < 1; // pixels stay square when zoomed in
    const wx = (Number(this.wipe.value) / 1000) * w;
    g.setTransform(dpr * s, 0, 0, dpr * s, dpr * ox, dpr * oy);
    g.drawImage(this.a.bitmap, 0, 0);
    g.save();
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.beginPath();
    g.rect(wx, 0, w - wx, h);
    g.clip();
    g.setTransform(dpr * s, 0, 0, dpr * s, dpr * ox, dpr * oy);
    g.drawImage(this.b.bitmap, 0, 0);
    g.restore();
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.fillStyle = '#ffffff';
    g.fillRect(Math.round(wx) - 1, 0, 2, h);
    this.stage.dataset.wipe = this.wipe.value;
  }

  private key(e: KeyboardEvent): void {
    const pan = 40;
    const k = e.key;
    if (k === 'ArrowLeft') this.panX += pan;
    else if (k === 'ArrowRight') this.panX -= pan;
    else if (k === 'ArrowUp') this.panY += pan;
    else if (k === 'ArrowDown') this.panY -= pan;
    else if (k === '+' || k === '=') return this.zoomBy(2), e.preventDefault();
    else if (k === '-') return this.zoomBy(0.5), e.preventDefault();
    else if (k === '0') return this.setScale(0), e.preventDefault();
    else if (k === '1') return this.setScale(1), e.preventDefault();
    else if (k === '[' || k === ']') {
      this.wipe.value = String(Number(this.wipe.value) + (k === '[' ? -50 : 50));
    } else return;
    e.preventDefault();
    this.draw();
  }

  private dragToPan(): void {
    let from: { x: number; y: number } | null = null;
    this.stage.addEventListener('pointerdown', (e) => {
      from = { x: e.clientX, y: e.clientY };
      this.stage.setPointerCapture(e.pointerId);
    });
    this.stage.addEventListener('pointermove', (e) => {
      if (!from) return;
      this.panX += e.clientX - from.x;
      this.panY += e.clientY - from.y;
      from = { x: e.clientX, y: e.clientY };
      this.draw();
    });
    const end = () => (from = null);
    this.stage.addEventListener('pointerup', end);
    this.stage.addEventListener('pointercancel', end);
  }

  /** As JobView's: a frame shown as processing is asked about again until it is idle. */
  private async refreshPending(): Promise<void> {
    if (!this.status?.pending || this.refreshing) return;
    this.refreshing = true;
    try {
      const st = await this.ctx.api.frame(this.jobId, this.frameNo);
      if (this.status && st.version >= this.status.version) {
        this.status = st;
        this.renderInfo();
      }
    } catch {
      // asked again at the next tick
    } finally {
      this.refreshing = false;
    }
  }

  destroy(): void {
    window.clearInterval(this.tick);
    this.chart?.destroy();
    this.resizeObs.disconnect();
    window.clearTimeout(this.exposureTimer);
  }
}
