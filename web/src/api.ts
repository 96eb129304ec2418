// The daemon's REST API (docs/api.md) as the dashboard uses it: JSON reads, pause/resume, image
// renditions as blobs with their colour-map headers. Every request carries the bearer token when
// one is set (reads need it unless the operator opened them: config `open_reads`).
import type { ColourMaps, FrameStatus, Job, QuarantineRecord, Version } from './types';

export class HttpError extends Error {
  constructor(
    readonly status: number,
    readonly code: string,
    message: string,
  ) {
    super(message);
  }
}

export interface ImageRendition {
  blob: Blob;
  version: number | null;
  colormap: string | null;
  scale: 'linear' | 'log' | null;
  range: [number, number] | null;
}

export interface ImageQuery {
  layer: string;
  version?: number; // an older version the daemon keeps (the farm integration's image?version=K)
  size?: number;
  exposure?: number;
  range?: [number, number];
}

const TOKEN_KEY = 'proden.token';

export class Api {
  onUnauthorized: () => void = () => {};

  constructor(
    readonly base = '',
    private fetchImpl: typeof fetch = fetch.bind(globalThis),
  ) {}

  get token(): string {
    return sessionStorage.getItem(TOKEN_KEY) ?? '';
  }
  set token(t: string) {
    if (t) sessionStorage.setItem(TOKEN_KEY, t);
    else sessionStorage.removeItem(TOKEN_KEY);
  }

  headers(): Record<string, string> {
    const t = this.token;
    return t ? { Authorization: `Bearer ${t}` } : {};
  }

  private async request(method: string, path: string): Promise<Response> {
    const res = await this.fetchImpl(this.base + path, {
      method,
      headers: this.headers(),
      cache: 'no-store',
    });
    if (!res.ok) {
      let code = 'http_' + res.status;
      let message = res.statusText;
      try {
        const j = await res.json();
        code = j.error?.code ?? code;
        message = j.error?.message ?? message;
      } catch {
        /* not JSON */
      }
      if (res.status === 401) this.onUnauthorized();
      throw new HttpError(res.status, code, message);
    }
    return res;
  }

  private async json<T>(path: string, method = 'GET'): Promise<T> {
    return (await (await this.request(method, path)).json()) as T;
  }

  jobs(): Promise<Job[]> {
    return this.json<{ jobs: Job[] }>('/api/v1/jobs').then((j) => j.jobs);
  }
  frames(job: string): Promise<FrameStatus[]> {
    return this.json<{ frames: FrameStatus[] }>(`/api/v1/jobs/${enc(job)}/frames`).then((j) => j.frames);
  }
  frame(job: string, frame: number): Promise<FrameStatus & Record<string, unknown>> {
    return this.json(`/api/v1/jobs/${enc(job)}/frames/${frame}`);
  }
  history(job: string, frame: number): Promise<Version[]> {
    return this.json<{ versions: Version[] }>(`/api/v1/jobs/${enc(job)}/frames/${frame}/history`).then(
      (j) => j.versions,
    );
  }
  jobHistory(job: string): Promise<{ frame: number; versions: Version[] }[]> {
    return this.json<{ frames: { frame: number; versions: Version[] }[] }>(
      `/api/v1/jobs/${enc(job)}/history`,
    ).then((j) => j.frames);
  }
  quarantine(job: string): Promise<QuarantineRecord[]> {
    return this.json<{ quarantined: QuarantineRecord[] }>(`/api/v1/jobs/${enc(job)}/quarantine`).then(
      (j) => j.quarantined,
    );
  }
  setPaused(job: string, paused: boolean): Promise<Job> {
    return this.json<Job>(`/api/v1/jobs/${enc(job)}/${paused ? 'pause' : 'resume'}`, 'POST');
  }
  colourMaps(): Promise<ColourMaps> {
    return this.json<ColourMaps>('/api/v1/colormaps');
  }
  async metrics(): Promise<string> {
    return (await this.request('GET', '/metrics')).text();
  }

  imageUrl(job: string, frame: number, q: ImageQuery): string {
    const p = new URLSearchParams({ format: 'png', layer: q.layer });
    if (q.size) p.set('size', String(q.size));
    if (q.exposure) p.set('exposure', String(q.exposure));
    if (q.range) p.set('range', `${q.range[0]},${q.range[1]}`);
    if (q.version) p.set('version', String(q.version));
    return `/api/v1/jobs/${enc(job)}/frames/${frame}/image?${p}`;
  }

  async image(job: string, frame: number, q: ImageQuery): Promise<ImageRendition> {
    const res = await this.request('GET', this.imageUrl(job, frame, q));
    const etag = res.headers.get('ETag') ?? '';
    const v = /^(\d+)$/.exec(res.headers.get('X-Proden-Version') ?? '') ?? /"v(\d+)/.exec(etag);
    const range = (res.headers.get('X-Proden-Range') ?? '').split(' ').map(Number);
    return {
      blob: await res.blob(),
      version: v ? Number(v[1]) : null,
      colormap: res.headers.get('X-Proden-Colormap'),
      scale: (res.headers.get('X-Proden-Scale') as 'linear' | 'log' | null) ?? null,
      range: range.length === 2 && range.every(Number.isFinite) ? [range[0], range[1]] : null,
    };
  }
}

function enc(s: string): string {
  return encodeURIComponent(s);
}
