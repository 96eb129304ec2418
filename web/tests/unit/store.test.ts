import { describe, expect, it } from 'vitest';
import { FrameBatcher } from '../../src/batch';
import { frameSeries } from '../../src/series';
import { Store, frameAfterEvent, mergeFrameSnapshot, mergeVersion, shotSpread, throughput } from '../../src/store';
import type { FrameEvent, Job, Version } from '../../src/types';

const job: Job = { id: 'j1', name: 'shot', state: 'active', created: '2026-01-01T00:00:00Z', output: { dir: '/o' } };
const t0 = Date.parse('2026-01-01T00:00:00Z');
const iso = (s: number) => new Date(t0 + s * 1000).toISOString();
const v = (version: number, passes: number, spp: number, mse: number, at: number, render?: number): Version => ({
  version,
  passes,
  spp,
  estimated_mse: mse,
  updated: iso(at),
  render_mse: render,
});
const ev = (frame: number, ver: Version): FrameEvent => ({ ...ver, job: 'j1', name: 'shot', frame, new_passes: 1 });

describe('mergeVersion', () => {
  it('keeps versions ascending, replaces a republished one, ignores an identical replay', () => {
    const list: Version[] = [];
    expect(mergeVersion(list, v(2, 2, 8, 0.1, 2))).toBe(true);
    expect(mergeVersion(list, v(1, 1, 4, 0.2, 1))).toBe(true);
    expect(mergeVersion(list, v(3, 3, 12, 0.05, 3))).toBe(true);
    expect(list.map((x) => x.version)).toEqual([1, 2, 3]);
    expect(mergeVersion(list, v(2, 2, 8, 0.1, 2))).toBe(false);
    expect(mergeVersion(list, v(2, 2, 8, 0.09, 5))).toBe(true);
    expect(list[1].estimated_mse).toBe(0.09);
    expect(list).toHaveLength(3);
  });
});

describe('frameAfterEvent', () => {
  it('takes newer versions only, keeps what the event lacks, clears pending', () => {
    const prev = { job: 'j1', frame: 3, passes: 1, spp: 4, version: 1, updated: iso(1), estimated_mse: 0.2, pending: true, converged: false };
    expect(frameAfterEvent(prev, ev(3, v(1, 1, 4, 0.2, 1)))).toBeNull();
    const next = frameAfterEvent(prev, ev(3, v(2, 2, 8, 0.1, 2)));
    expect(next).toMatchObject({ version: 2, passes: 2, spp: 8, estimated_mse: 0.1, pending: false, converged: false });
    expect(frameAfterEvent(undefined, { ...ev(4, v(1, 1, 4, 0.3, 1)), converged: true })).toMatchObject({ frame: 4, converged: true });
  });
});

describe('mergeFrameSnapshot', () => {
  const st = (version: number, pending: boolean) => ({ job: 'j1', frame: 2, passes: version, spp: 4 * version, version, updated: iso(version), estimated_mse: 0.1, pending });
  it('keeps the versions events brought while the answers were in flight', () => {
    const m = mergeFrameSnapshot(st(1, true), [v(1, 1, 4, 0.2, 1)], st(2, false), [v(2, 2, 8, 0.1, 2)]);
    expect(m.status).toMatchObject({ version: 2, pending: false });
    expect(m.versions.map((x) => x.version)).toEqual([1, 2]);
  });
  it('takes the answers when they are as new as the events', () => {
    const m = mergeFrameSnapshot(st(2, true), [v(1, 1, 4, 0.2, 1), v(2, 2, 8, 0.1, 2)], st(2, false), [v(2, 2, 8, 0.3, 2)]);
    expect(m.status).toMatchObject({ version: 2, pending: true });
    expect(m.versions.map((x) => x.estimated_mse)).toEqual([0.2, 0.1]);
  });
});

describe('Store', () => {
  it('applies events to known jobs only, and replays change nothing', () => {
    const s = new Store();
    s.setJobs([job]);
    expect(s.applyFrameEvent({ ...ev(1, v(1, 1, 4, 0.2, 1)), job: 'other' })).toBe(false);
    expect(s.applyFrameEvent(ev(1, v(1, 1, 4, 0.2, 1)))).toBe(true);
    expect(s.applyFrameEvent(ev(1, v(1, 1, 4, 0.2, 1)))).toBe(false);
    expect(s.jobs.get('j1')!.frames.get(1)!.version).toBe(1);
    expect(s.jobs.get('j1')!.versions.get(1)).toHaveLength(1);
  });

  it('reports the frames a snapshot changed, including removed ones', () => {
    const s = new Store();
    s.setJobs([job]);
    const f = (frame: number, version: number) => ({ job: 'j1', frame, passes: version, spp: 4 * version, version, updated: iso(version), estimated_mse: 0.1, pending: false });
    expect(s.setFrames('j1', [f(1, 1), f(2, 1)]).sort()).toEqual([1, 2]);
    expect(s.setFrames('j1', [f(1, 1), f(2, 2)])).toEqual([2]);
    expect(s.setFrames('j1', [f(2, 2)])).toEqual([1]);
  });

  it('keeps an event newer than a snapshot that was answered before it', () => {
    const s = new Store();
    s.setJobs([job]);
    // the page asked for the frames while frame 5 ran (version 0, pending), then its version-1
    // event arrived before the answer did
    s.applyFrameEvent(ev(5, v(1, 1, 4, 0.2, 1)));
    const stale = { job: 'j1', frame: 5, passes: 0, spp: 0, version: 0, updated: '', estimated_mse: 0, pending: true };
    expect(s.setFrames('j1', [stale])).toEqual([]);
    expect(s.jobs.get('j1')!.frames.get(5)).toMatchObject({ version: 1, pending: false });
    // a snapshot at the same version is the daemon's newer word on it: more passes wait
    expect(s.setFrames('j1', [{ ...stale, version: 1, passes: 1, spp: 4, pending: true }])).toEqual([5]);
    expect(s.jobs.get('j1')!.frames.get(5)!.pending).toBe(true);
  });

  it('takes a converged event for a known frame', () => {
    const s = new Store();
    s.setJobs([job]);
    expect(s.applyConverged('j1', 1, true)).toBe(false); // no such frame yet
    s.applyFrameEvent(ev(1, v(1, 1, 4, 0.2, 1)));
    expect(s.applyConverged('j1', 1, true)).toBe(true);
    expect(s.applyConverged('j1', 1, true)).toBe(false);
    expect(s.jobs.get('j1')!.frames.get(1)!.converged).toBe(true);
    // a later version keeps the flag unless its event says otherwise
    s.applyFrameEvent(ev(1, v(2, 2, 8, 0.1, 2)));
    expect(s.jobs.get('j1')!.frames.get(1)!.converged).toBe(true);
  });

  it('bounds the error list', () => {
    const s = new Store();
    s.setJobs([job]);
    for (let i = 0; i < 500; i++) s.applyErrorEvent({ job: 'j1', frame: i, pass: '', path: '', kind: 'unreadable', message: '', quarantined: false });
    expect(s.jobs.get('j1')!.errors).toHaveLength(200);
    expect(s.jobs.get('j1')!.errors[199].frame).toBe(499);
  });
});

describe('throughput', () => {
  it('counts new passes and versions in the window, per minute', () => {
    const versions = new Map([
      [1, [v(1, 2, 8, 0.1, 0), v(2, 3, 12, 0.05, 30)]],
      [2, [v(1, 1, 4, 0.2, 60)]],
    ]);
    // 4 passes and 3 versions between t=0 and t=60 s: 4 and 3 per minute
    expect(throughput(versions, t0 + 60_000)).toEqual({ passesPerMin: 4, updatesPerMin: 3 });
    // a 20 s window at t=60 s holds only frame 2's version (1 pass)
    expect(throughput(versions, t0 + 60_000, 20_000)).toEqual({ passesPerMin: 3, updatesPerMin: 3 });
  });
});

describe('shotSpread', () => {
  it('gives each spp level the spread of the frames that reached it', () => {
    const versions = new Map([
      [1, [v(1, 1, 4, 0.4, 0, 1.0), v(2, 2, 8, 0.2, 1, 0.5)]],
      [2, [v(1, 1, 4, 0.2, 0, 0.8), v(2, 3, 12, 0.05, 1, 0.3)]],
      [3, [v(1, 2, 8, 0.1, 0, 0.6)]],
    ]);
    const s = shotSpread(versions);
    expect(s.spp).toEqual([4, 8, 12]);
    expect(s.frames).toEqual([2, 3, 3]);
    expect(s.min).toEqual([0.2, 0.1, 0.05]);
    expect(s.max).toEqual([0.4, 0.2, 0.2]); // frame 1 stays at its 8-spp error
    expect(s.median).toEqual([0.30000000000000004, 0.2, 0.1]);
    expect(s.renderMedian).toEqual([0.9, 0.6, 0.5]);
  });

  it('uses the calibrated estimate when a version carries one', () => {
    const a = { ...v(1, 1, 4, 0.4, 0), estimated_error: { mse: 0.9 } };
    expect(shotSpread(new Map([[1, [a]]])).median).toEqual([0.9]);
  });
});

describe('FrameBatcher', () => {
  it('coalesces any number of marks into one flush per animation frame', () => {
    const frames: (() => void)[] = [];
    const flushes: number[][] = [];
    const b = new FrameBatcher<number>((keys) => flushes.push([...keys]), (cb) => frames.push(cb));
    for (let i = 0; i < 1000; i++) b.mark(i % 500); // 1000 events over 500 frames
    expect(frames).toHaveLength(1);
    frames.shift()!();
    expect(flushes).toHaveLength(1);
    expect(flushes[0]).toHaveLength(500);
    b.mark(7);
    frames.shift()!();
    expect(flushes[1]).toEqual([7]);
  });
});

describe('frameSeries', () => {
  it('orders versions by x, drops non-positive values, carries the interval when given', () => {
    const a = { ...v(2, 2, 8, 0.1, 20, 0.3), estimated_error: { mse: 0.1, mse_low: 0.08, mse_high: 0.13 } };
    const b = v(1, 1, 4, 0.2, 10, 0.5);
    const c = v(3, 3, 12, 0, 30); // a zero estimate cannot sit on a log axis
    expect(frameSeries([a, b, c], 'spp', t0)).toEqual([
      [4, 8, 12],
      [0.2, 0.1, null],
      [0.5, 0.3, null],
      [null, 0.08, null],
      [null, 0.13, null],
    ]);
    expect(frameSeries([b, a], 'time', t0)[0]).toEqual([10, 20]); // seconds since the origin
    expect(frameSeries([b], 'time', t0 + 10_000)[0]).toEqual([]); // not after the origin
  });
});
