// The daemon's health from GET /metrics (Prometheus text format 0.0.4): queue length, worker
// utilisation and per-stage times, as rates between two scrapes.

export interface Sample {
  name: string;
  labels: Record<string, string>;
  value: number;
}

/** Parses the text exposition format (comments and TYPE/HELP lines skipped). */
export function parsePrometheus(text: string): Sample[] {
  const out: Sample[] = [];
  for (const raw of text.split('\n')) {
    const line = raw.trim();
    if (!line || line.startsWith('#')) continue;
    const m = /^([a-zA-Z_:][a-zA-Z0-9_:]*)(\{(.*)\})?\s+(\S+)(\s+\S+)?$/.exec(line);
    if (!m) continue;
    const labels: Record<string, string> = {};
    if (m[3]) {
      const re = /([a-zA-Z_][a-zA-Z0-9_]*)="((?:[^"\\]|\\.)*)"\s*,?/g;
      let l: RegExpExecArray | null;
      while ((l = re.exec(m[3]))) labels[l[1]] = l[2].replace(/\\(.)/g, (_, c) => (c === 'n' ? '\n' : c));
    }
    const v = m[4];
    const value = v === '+Inf' ? Infinity : v === '-Inf' ? -Infinity : Number(v);
    out.push({ name: m[1], labels, value });
  }
  return out;
}

export interface Scrape {
  at: number; // ms
  samples: Sample[];
}

function value(s: Sample[], name: string, labels: Record<string, string> = {}): number | undefined {
  return s.find((x) => x.name === name && Object.entries(labels).every(([k, v]) => x.labels[k] === v))
    ?.value;
}

export interface StageTime {
  stage: string;
  seconds: number; // mean per run: over the last interval when it had runs, else since start
  recent: boolean;
  count: number;
}

export interface Health {
  queue: number;
  inProgress: number;
  workers: number;
  utilisation: number | null; // busy worker-seconds per worker per second over the interval
  sseClients: number;
  passes: number;
  updates: number;
  errors: number;
  stages: StageTime[];
}

/** Health now (`cur`), with rates over the interval since `prev` when given. */
export function health(cur: Scrape, prev?: Scrape): Health {
  const s = cur.samples;
  const workers = value(s, 'proden_worker_threads') ?? 0;
  let utilisation: number | null = null;
  if (prev && workers > 0 && cur.at > prev.at) {
    const b1 = value(s, 'proden_worker_busy_seconds_total');
    const b0 = value(prev.samples, 'proden_worker_busy_seconds_total');
    if (b1 !== undefined && b0 !== undefined) {
      utilisation = Math.min(1, Math.max(0, (b1 - b0) / ((cur.at - prev.at) / 1000) / workers));
    }
  }
  const stages: StageTime[] = [];
  for (const x of s) {
    if (x.name !== 'proden_stage_duration_seconds_sum') continue;
    const stage = x.labels.stage;
    const count = value(s, 'proden_stage_duration_seconds_count', { stage }) ?? 0;
    if (count <= 0) continue;
    let seconds = x.value / count;
    let recent = false;
    if (prev) {
      const s0 = value(prev.samples, 'proden_stage_duration_seconds_sum', { stage }) ?? 0;
      const c0 = value(prev.samples, 'proden_stage_duration_seconds_count', { stage }) ?? 0;
      if (count > c0) {
        seconds = (x.value - s0) / (count - c0);
        recent = true;
      }
    }
    stages.push({ stage, seconds, recent, count });
  }
  const errors = s
    .filter((x) => x.name === 'proden_errors_total' && !String(x.labels.kind ?? '').startsWith('http_'))
    .reduce((a, x) => a + x.value, 0);
  return {
    queue: value(s, 'proden_queue_depth') ?? 0,
    inProgress: value(s, 'proden_frames_in_progress') ?? 0,
    workers,
    utilisation,
    sseClients: value(s, 'proden_sse_clients') ?? 0,
    passes: value(s, 'proden_passes_ingested_total') ?? 0,
    updates: value(s, 'proden_frame_updates_total') ?? 0,
    errors,
    stages,
  };
}
