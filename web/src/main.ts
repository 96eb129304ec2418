// The dashboard's shell: hash routes (#/, #/job/ID, #/job/ID/frame/N), the event stream that
// keeps every page live (resuming with Last-Event-ID, resynchronising after a reconnect), the
// connection indicator and the token prompt.
import './style.css';
import { Api, HttpError } from './api';
import { el } from './format';
import { EventStream, type StreamState } from './sse';
import { Store } from './store';
import type { ColourMaps, ErrorEvent, FrameEvent, JobEvent } from './types';
import { FrameView } from './views/frame';
import { JobView } from './views/job';
import { OverviewView } from './views/overview';
import type { Ctx, View } from './views/view';

const api = new Api();
const store = new Store();
const main = document.getElementById('main') as HTMLElement;
const crumbs = document.getElementById('crumbs') as HTMLElement;
const conn = document.getElementById('conn') as HTMLElement;
const live = el('div', { class: 'sr-only', 'aria-live': 'polite' });
document.body.append(live);

let maps: Promise<ColourMaps> | null = null;
const ctx: Ctx = {
  api,
  store,
  colourMaps: () => (maps ??= api.colourMaps().catch((e) => ((maps = null), Promise.reject(e)))),
  announce: (text) => {
    live.textContent = text;
  },
};

let view: View | null = null;

function route(): void {
  view?.destroy();
  const h = location.hash.replace(/^#\/?/, '').split('/').map(decodeURIComponent);
  if (h[0] === 'job' && h[1] && h[2] === 'frame' && /^\d+$/.test(h[3] ?? '')) {
    view = new FrameView(ctx, h[1], Number(h[3]));
  } else if (h[0] === 'job' && h[1]) {
    view = new JobView(ctx, h[1]);
  } else {
    view = new OverviewView(ctx);
  }
  main.replaceChildren(view.el);
  document.body.dataset.view = view.constructor.name;
  void load(view);
}

async function load(v: View): Promise<void> {
  try {
    await v.resync();
    if (v !== view) return;
    crumbs.replaceChildren(
      ...v.crumbs.flatMap((c, i) => [
        el('span', { class: 'sep', 'aria-hidden': 'true', text: '/' }),
        el('a', { href: c.href, ...(i === v.crumbs.length - 1 ? { 'aria-current': 'page' } : {}), text: c.label }),
      ]),
    );
    document.body.dataset.ready = 'true';
  } catch (e) {
    if (v !== view) return;
    if (e instanceof HttpError && e.status === 401) return; // the token prompt is up
    main.replaceChildren(
      el('section', { class: 'panel error', role: 'alert' }, el('h1', { text: 'Not available' }), el('p', { text: (e as Error).message })),
    );
  }
}

const STATE_TEXT: Record<StreamState, string> = {
  connecting: '◌ connecting…',
  open: '● live',
  reconnecting: '◌ reconnecting…',
  unauthorized: '✗ token needed',
  stopped: '○ stopped',
};

const stream = new EventStream({
  url: '/api/v1/events',
  headers: () => api.headers(),
  onState: (s, detail) => {
    conn.textContent = STATE_TEXT[s];
    conn.className = `conn conn-${s}`;
    conn.title = detail ?? '';
    document.body.dataset.stream = s;
    if (s === 'unauthorized') askToken();
  },
  onReconnect: () => {
    if (view) void load(view); // events may have been missed (e.g. the daemon restarted)
  },
  onEvent: (e) => {
    let data: unknown;
    try {
      data = JSON.parse(e.data);
    } catch {
      return;
    }
    if (e.event === 'frame') {
      const fe = data as FrameEvent;
      if (!store.jobs.has(fe.job)) return;
      if (store.applyFrameEvent(fe)) view?.onFrame?.(fe);
    } else if (e.event === 'job') {
      view?.onJob?.(data as JobEvent);
    } else if (e.event === 'error') {
      const ee = data as ErrorEvent;
      store.applyErrorEvent(ee);
      view?.onError?.(ee);
    } else {
      // The farm integration's `converged` / `unconverged` events, and any other event that names
      // a frame and its `converged` state.
      const c = data as { job?: string; frame?: number; converged?: boolean };
      const state = e.event === 'converged' ? true : e.event === 'unconverged' ? false : c.converged;
      if (typeof c.job === 'string' && typeof c.frame === 'number' && typeof state === 'boolean') {
        if (store.applyConverged(c.job, c.frame, state)) {
          const f = store.jobs.get(c.job)?.frames.get(c.frame);
          if (f) view?.onFrame?.({ ...f, name: '', new_passes: 0, updated: f.updated ?? '' });
        }
      }
    }
  },
});

const dialog = document.getElementById('token-dialog') as HTMLDialogElement;
const tokenInput = document.getElementById('token-input') as HTMLInputElement;
function askToken(): void {
  if (!dialog.open) {
    tokenInput.value = api.token;
    dialog.showModal();
  }
}
dialog.addEventListener('close', () => {
  if (dialog.returnValue === 'ok') {
    api.token = tokenInput.value.trim();
    stream.kick();
    if (view) void load(view);
  }
});
document.getElementById('token-btn')?.addEventListener('click', askToken);
api.onUnauthorized = askToken;

window.addEventListener('hashchange', () => {
  route();
  main.focus();
});
route();
stream.start();
