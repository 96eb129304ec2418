import { describe, expect, it } from 'vitest';
import { health, parsePrometheus } from '../../src/metrics';
import { decades, sci } from '../../src/format';

const scrape = (busy: number, sum: number, count: number) => `# HELP proden_queue_depth Frames waiting
# TYPE proden_queue_depth gauge
proden_queue_depth 3
proden_frames_in_progress 1
proden_worker_threads 2
proden_worker_busy_seconds_total ${busy}
proden_errors_total{kind="unreadable"} 2
proden_errors_total{kind="http_404"} 9
proden_stage_duration_seconds_bucket{stage="denoise",le="+Inf"} ${count}
proden_stage_duration_seconds_sum{stage="denoise"} ${sum}
proden_stage_duration_seconds_count{stage="denoise"} ${count}
`;

describe('parsePrometheus', () => {
  it('reads names, labels (with escapes) and special values', () => {
    const s = parsePrometheus('a_total{kind="x\\"y",b="2"} 4\nc +Inf\n# comment\nd 1e-3 1700000000\n');
    expect(s).toEqual([
      { name: 'a_total', labels: { kind: 'x"y', b: '2' }, value: 4 },
      { name: 'c', labels: {}, value: Infinity },
      { name: 'd', labels: {}, value: 0.001 },
    ]);
  });
});

describe('health', () => {
  it('takes utilisation and recent stage times from the difference of two scrapes', () => {
    const a = { at: 0, samples: parsePrometheus(scrape(10, 4, 8)) };
    const b = { at: 2000, samples: parsePrometheus(scrape(12, 7, 10)) };
    const h = health(b, a);
    expect(h.queue).toBe(3);
    expect(h.inProgress).toBe(1);
    expect(h.workers).toBe(2);
    expect(h.utilisation).toBeCloseTo(0.5); // 2 busy seconds over 2 s and 2 workers
    expect(h.errors).toBe(2); // HTTP errors are not the farm's
    expect(h.stages).toEqual([{ stage: 'denoise', seconds: 1.5, recent: true, count: 10 }]);
    const first = health(a);
    expect(first.utilisation).toBeNull();
    expect(first.stages[0]).toMatchObject({ seconds: 0.5, recent: false });
  });
});

describe('formats', () => {
  it('prints errors readably and keeps integers whole', () => {
    expect(sci(10, 1)).toBe('10');
    expect(sci(0.0016)).toBe('1.6e-3');
    expect(sci(0.0125)).toBe('0.0125');
    expect(sci(NaN)).toBe('–');
    expect(decades(1e-7, 0.01)).toEqual([1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2].map((x) => 10 ** Math.round(Math.log10(x))));
  });
});
