// The dashboard's data: jobs, their frames, each frame's published versions and errors, kept up to
// date from REST snapshots and SSE events. Pure data handling (no DOM): views ask it what changed.
import type { ErrorEvent, FrameEvent, FrameStatus, Job, QuarantineRecord, Version } from './types';
import { errorOf } from './types';

export interface JobData {
  job: Job;
  frames: Map<number, FrameStatus>;
  versions: Map<number, Version[]>; // per frame, ascending version
  quarantined: QuarantineRecord[];
  errors: ErrorEvent[]; // recent error events (newest last), bounded
  historyLoaded: boolean;
}

export const MAX_ERRORS = 200;

/** Inserts or replaces `v` in `list` (ascending by version). Returns true if the list changed. */
export function mergeVersion(list: Version[], v: Version): boolean {
  let i = list.length;
  while (i > 0 && list[i - 1].version > v.version) i--;
  if (i > 0 && list[i - 1].version === v.version) {
    const old = list[i - 1];
    if (old.updated === v.updated && old.passes === v.passes && errorOf(old) === errorOf(v)) return false;
    list[i - 1] = v;
    return true;
  }
  list.splice(i, 0, v);
  return true;
}

export function versionOfEvent(e: FrameEvent): Version {
  const { version, updated, passes, spp, estimated_mse, estimated_error, render_mse, converged } = e;
  return { version, updated, passes, spp, estimated_mse, estimated_error, render_mse, converged };
}

/** Frame status after event `e` (a newer version only; stale or replayed events change nothing). */
export function frameAfterEvent(prev: FrameStatus | undefined, e: FrameEvent): FrameStatus | null {
  if (prev && prev.version >= e.version) return null;
  return {
    ...(prev ?? { job: e.job, frame: e.frame, pending: false }),
    job: e.job,
    frame: e.frame,
    passes: e.passes,
    spp: e.spp,
    version: e.version,
    updated: e.updated,
    estimated_mse: e.estimated_mse,
    estimated_error: e.estimated_error ?? prev?.estimated_error,
    converged: e.converged ?? prev?.converged,
    pending: false, // this run ended; a snapshot tells whether more passes wait
  };
}

/**
 * One frame's REST answers (status and history) merged with what events already brought while
 * they were in flight: a frame's versions only grow, so the newer status wins, and the history
 * gains the versions the answer was too early for.
 */
export function mergeFrameSnapshot(
  status: FrameStatus,
  versions: Version[],
  known: FrameStatus | undefined,
  knownVersions: Version[] = [],
): { status: FrameStatus; versions: Version[] } {
  const list = [...versions];
  const last = list.length ? list[list.length - 1].version : 0;
  for (const v of knownVersions) if (v.version > last) mergeVersion(list, v);
  return { status: known && known.version > status.version ? { ...status, ...known } : status, versions: list };
}

export interface Throughput {
  passesPerMin: number;
  updatesPerMin: number;
}

/**
 * Passes ingested and versions published per minute over the `windowMs` before `now`, from the
 * frames' versions (a version's new passes = its pass count minus the previous version's). The
 * window starts no earlier than the first version seen, and spans at least 10 s.
 */
export function throughput(versions: Map<number, Version[]>, now: number, windowMs = 5 * 60_000): Throughput {
  const from = now - windowMs;
  let passes = 0;
  let updates = 0;
  let first = Infinity;
  for (const list of versions.values()) {
    let prevPasses = 0;
    for (const v of list) {
      const t = Date.parse(v.updated);
      if (Number.isFinite(t)) first = Math.min(first, t);
      if (Number.isFinite(t) && t > from && t <= now) {
        passes += Math.max(0, v.passes - prevPasses);
        updates += 1;
      }
      prevPasses = v.passes;
    }
  }
  const start = Math.max(from, first);
  const span = Math.max(now - start, 10_000);
  return { passesPerMin: (passes * 60_000) / span, updatesPerMin: (updates * 60_000) / span };
}

export interface Spread {
  spp: number[];
  min: number[];
  median: number[];
  max: number[];
  renderMedian: (number | null)[];
  frames: number[]; // how many frames reached each spp
}

function median(sorted: number[]): number {
  const n = sorted.length;
  return n % 2 ? sorted[(n - 1) / 2] : 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]);
}

/**
 * The shot's accuracy against samples: at each spp level any frame published, the spread (min,
 * median, max) over the frames that reached it of their estimated error at that level (each
 * frame's last version with spp <= level), and the median of the plain render's.
 */
export function shotSpread(versions: Map<number, Version[]>): Spread {
  const levels = new Set<number>();
  for (const list of versions.values()) for (const v of list) if (v.spp > 0) levels.add(v.spp);
  const spp = [...levels].sort((a, b) => a - b);
  const out: Spread = { spp: [], min: [], median: [], max: [], renderMedian: [], frames: [] };
  const lists = [...versions.values()].filter((l) => l.length > 0);
  const cursor = lists.map(() => -1);
  for (const level of spp) {
    const errs: number[] = [];
    const renders: number[] = [];
    lists.forEach((list, i) => {
      let k = cursor[i];
      while (k + 1 < list.length && list[k + 1].spp <= level) k++;
      cursor[i] = k;
      if (k < 0) return;
      const e = errorOf(list[k]);
      if (Number.isFinite(e) && e > 0) errs.push(e);
      const r = list[k].render_mse;
      if (typeof r === 'number' && r > 0) renders.push(r);
    });
    if (errs.length === 0) continue;
    errs.sort((a, b) => a - b);
    renders.sort((a, b) => a - b);
    out.spp.push(level);
    out.min.push(errs[0]);
    out.median.push(median(errs));
    out.max.push(errs[errs.length - 1]);
    out.renderMedian.push(renders.length ? median(renders) : null);
    out.frames.push(errs.length);
  }
  return out;
}

/** Summary of a job for the jobs table. */
export function jobSummary(d: JobData): {
  frames: number;
  published: number;
  converged: number;
  pending: number;
  passes: number;
} {
  let published = 0;
  let converged = 0;
  let pending = 0;
  let passes = 0;
  for (const f of d.frames.values()) {
    if (f.version > 0) published++;
    if (f.converged) converged++;
    if (f.pending) pending++;
    passes += f.passes;
  }
  return { frames: d.frames.size, published, converged, pending, passes };
}

export class Store {
  readonly jobs = new Map<string, JobData>();

  setJobs(list: Job[]): void {
    const ids = new Set(list.map((j) => j.id));
    for (const id of [...this.jobs.keys()]) if (!ids.has(id)) this.jobs.delete(id);
    for (const job of list) {
      const d = this.jobs.get(job.id);
      if (d) d.job = job;
      else this.jobs.set(job.id, this.empty(job));
    }
  }

  private empty(job: Job): JobData {
    return { job, frames: new Map(), versions: new Map(), quarantined: [], errors: [], historyLoaded: false };
  }

  /**
   * Replaces a job's frames with a snapshot; returns the frames whose status changed. A frame's
   * versions only grow, so a snapshot older than an event already applied (the request was answered
   * before the version was published, the event arrived first) keeps the event's status.
   */
  setFrames(jobId: string, frames: FrameStatus[]): number[] {
    const d = this.jobs.get(jobId);
    if (!d) return [];
    const changed: number[] = [];
    const seen = new Set<number>();
    for (const f of frames) {
      seen.add(f.frame);
      const old = d.frames.get(f.frame);
      if (old && old.version > f.version) continue;
      if (
        !old ||
        old.version !== f.version ||
        old.pending !== f.pending ||
        old.passes !== f.passes ||
        old.converged !== f.converged
      ) {
        changed.push(f.frame);
      }
      d.frames.set(f.frame, f);
    }
    for (const n of [...d.frames.keys()]) {
      if (!seen.has(n)) {
        d.frames.delete(n);
        changed.push(n);
      }
    }
    return changed;
  }

  setHistory(jobId: string, frames: { frame: number; versions: Version[] }[]): void {
    const d = this.jobs.get(jobId);
    if (!d) return;
    for (const { frame, versions } of frames) {
      const list = d.versions.get(frame) ?? [];
      for (const v of versions) mergeVersion(list, v);
      d.versions.set(frame, list);
    }
    d.historyLoaded = true;
  }

  /** Applies a `frame` event; returns true when the frame's status or history changed. */
  applyFrameEvent(e: FrameEvent): boolean {
    const d = this.jobs.get(e.job);
    if (!d) return false;
    const list = d.versions.get(e.frame) ?? [];
    d.versions.set(e.frame, list);
    const historyChanged = mergeVersion(list, versionOfEvent(e));
    const next = frameAfterEvent(d.frames.get(e.frame), e);
    if (next) d.frames.set(e.frame, next);
    return historyChanged || next !== null;
  }

  /**
   * An event that says a frame converged (or not) without publishing a version (the farm
   * integration's `converged` event): sets the flag; true when it changed.
   */
  applyConverged(jobId: string, frame: number, converged: boolean): boolean {
    const f = this.jobs.get(jobId)?.frames.get(frame);
    if (!f || f.converged === converged) return false;
    this.jobs.get(jobId)!.frames.set(frame, { ...f, converged });
    return true;
  }

  applyErrorEvent(e: ErrorEvent): boolean {
    const d = this.jobs.get(e.job);
    if (!d) return false;
    d.errors.push(e);
    if (d.errors.length > MAX_ERRORS) d.errors.splice(0, d.errors.length - MAX_ERRORS);
    return true;
  }

  setPaused(jobId: string, paused: boolean): void {
    const d = this.jobs.get(jobId);
    if (d) d.job = { ...d.job, state: paused ? 'paused' : 'active' };
  }
}
