// The overview: every job (state, frames, passes, throughput, errors, pause/resume) and the
// daemon's health from /metrics (queue, worker utilisation, stage times).
import { FrameBatcher } from '../batch';
import { el, fixed, seconds } from '../format';
import { health, parsePrometheus, type Health, type Scrape } from '../metrics';
import { jobSummary, throughput } from '../store';
import type { Ctx, View } from './view';
import { pauseButton } from './job';

export class HealthPanel {
  readonly el = el('section', { class: 'panel health', 'aria-labelledby': 'health-h' });
  private prev: Scrape | undefined;
  private timer: number | undefined;
  private body = el('div');

  constructor(private ctx: Ctx) {
    this.el.append(el('h2', { id: 'health-h', text: 'Daemon health' }), this.body);
    void this.poll();
    this.timer = window.setInterval(() => void this.poll(), 2000);
  }

  private async poll(): Promise<void> {
    try {
      const cur: Scrape = { at: Date.now(), samples: parsePrometheus(await this.ctx.api.metrics()) };
      this.render(health(cur, this.prev));
      this.prev = cur;
    } catch {
      /* the connection indicator reports it */
    }
  }

  private render(h: Health): void {
    const util = h.utilisation === null ? '–' : `${(h.utilisation * 100).toFixed(0)} %`;
    const kv = el(
      'dl',
      { class: 'kv' },
      el('dt', { text: 'Queue' }),
      el('dd', { 'data-metric': 'queue', text: `${h.queue} frame(s) waiting` }),
      el('dt', { text: 'Workers' }),
      el('dd', { 'data-metric': 'workers', text: `${h.inProgress} of ${h.workers} busy` }),
      el('dt', { text: 'Utilisation' }),
      el('dd', { 'data-metric': 'utilisation' }, meter(h.utilisation ?? 0, util)),
      el('dt', { text: 'Ingested' }),
      el('dd', { text: `${h.passes} passes, ${h.updates} versions, ${h.errors} errors` }),
      el('dt', { text: 'Live clients' }),
      el('dd', { text: String(h.sseClients) }),
    );
    const stages = [...h.stages].sort((a, b) => b.seconds - a.seconds);
    const max = Math.max(1e-9, ...stages.map((s) => s.seconds));
    const table = el(
      'table',
      { class: 'stages' },
      el('caption', { text: 'Stage times (mean per run; last 2 s when it ran, else since start)' }),
      el('thead', {}, el('tr', {}, el('th', { text: 'stage' }), el('th', { text: 'time' }), el('th', { text: 'runs' }))),
      el(
        'tbody',
        {},
        ...stages.map((s) =>
          el(
            'tr',
            {},
            el('th', { scope: 'row', text: s.stage }),
            el('td', {}, meter(s.seconds / max, seconds(s.seconds))),
            el('td', { class: 'num', text: String(s.count) }),
          ),
        ),
      ),
    );
    this.body.replaceChildren(kv, table);
  }

  destroy(): void {
    window.clearInterval(this.timer);
  }
}

function meter(fraction: number, label: string): HTMLElement {
  const bar = el('span', { class: 'meter', 'aria-hidden': 'true' }, el('span', { class: 'fill' }));
  (bar.firstChild as HTMLElement).style.width = `${Math.round(Math.min(1, Math.max(0, fraction)) * 100)}%`;
  return el('span', { class: 'metered' }, bar, el('span', { text: label }));
}

export class OverviewView implements View {
  readonly el = el('div', { class: 'overview' });
  readonly crumbs = [];
  private table = el('tbody');
  private health: HealthPanel;
  private tick: number;
  private batch = new FrameBatcher<number>(() => this.render());

  constructor(private ctx: Ctx) {
    this.health = new HealthPanel(ctx);
    const jobs = el(
      'section',
      { class: 'panel', 'aria-labelledby': 'jobs-h' },
      el('h2', { id: 'jobs-h', text: 'Jobs' }),
      el(
        'table',
        { class: 'jobs' },
        el(
          'thead',
          {},
          el(
            'tr',
            {},
            ...['job', 'state', 'frames', 'passes', 'passes/min', 'versions/min', 'errors', ''].map((t) =>
              el('th', { scope: 'col', text: t }),
            ),
          ),
        ),
        this.table,
      ),
    );
    this.el.append(jobs, this.health.el);
    this.tick = window.setInterval(() => this.render(), 5000);
  }

  async resync(): Promise<void> {
    const { api, store } = this.ctx;
    store.setJobs(await api.jobs());
    await Promise.all(
      [...store.jobs.keys()].map(async (id) => {
        const [frames, hist, q] = await Promise.all([api.frames(id), api.jobHistory(id), api.quarantine(id)]);
        store.setFrames(id, frames);
        store.setHistory(id, hist);
        const d = store.jobs.get(id);
        if (d) d.quarantined = q;
      }),
    );
    this.render();
  }

  private render(): void {
    const rows = [...this.ctx.store.jobs.values()].map((d) => {
      const s = jobSummary(d);
      const t = throughput(d.versions, Date.now());
      const nErr = d.quarantined.length;
      return el(
        'tr',
        { 'data-job': d.job.id },
        el('th', { scope: 'row' }, el('a', { href: `#/job/${d.job.id}`, text: d.job.name })),
        el('td', {}, stateChip(d.job.state)),
        el('td', { class: 'num', text: `${s.published}/${s.frames}${s.converged ? ` (${s.converged} converged)` : ''}` }),
        el('td', { class: 'num', text: String(s.passes) }),
        el('td', { class: 'num', text: fixed(t.passesPerMin) }),
        el('td', { class: 'num', text: fixed(t.updatesPerMin) }),
        el('td', { class: 'num', text: nErr ? `⚠ ${nErr} quarantined` : '0' }),
        el('td', {}, pauseButton(this.ctx, d.job.id)),
      );
    });
    if (rows.length === 0) {
      rows.push(el('tr', {}, el('td', { colspan: '8', text: 'No jobs yet: POST /api/v1/jobs (docs/api.md).' })));
    }
    this.table.replaceChildren(...rows);
  }

  onFrame(): void {
    this.batch.mark(0);
  }
  onJob(): void {
    void this.resync();
  }
  onError(): void {
    void this.resync();
  }

  destroy(): void {
    this.health.destroy();
    window.clearInterval(this.tick);
  }
}

export function stateChip(state: string): HTMLElement {
  const icon = state === 'paused' ? '‖' : '▶';
  return el('span', { class: `chip state-${state}`, text: `${icon} ${state}` });
}
