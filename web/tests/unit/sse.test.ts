import { describe, expect, it } from 'vitest';
import { EventStream, SseParser, backoff, type SseEvent, type StreamState } from '../../src/sse';

describe('SseParser', () => {
  it('parses the daemon events, comments and retry', () => {
    const p = new SseParser();
    const evs = p.feed('retry: 2000\n\n: keep-alive\n\nid: 17\nevent: frame\ndata: {"frame":1}\n\n');
    expect(evs).toEqual([{ id: '17', event: 'frame', data: '{"frame":1}' }]);
    expect(p.retry).toBe(2000);
    expect(p.lastEventId).toBe('17');
  });

  it('joins events split at any byte, and CRLF split across chunks', () => {
    const text = 'id: 1\r\nevent: job\r\ndata: a\r\ndata: b\r\n\r\nid: 2\nevent: frame\ndata: c\n\n';
    for (let cut = 1; cut < text.length; cut++) {
      const p = new SseParser();
      const evs = [...p.feed(text.slice(0, cut)), ...p.feed(text.slice(cut))];
      expect(evs, `cut at ${cut}`).toEqual([
        { id: '1', event: 'job', data: 'a\nb' },
        { id: '2', event: 'frame', data: 'c' },
      ]);
    }
  });

  it('keeps the last id for events without one, and ignores unknown fields', () => {
    const p = new SseParser();
    const evs = p.feed('id: 5\ndata: x\n\nfoo: bar\ndata: y\n\n');
    expect(evs.map((e) => e.id)).toEqual(['5', '5']);
    expect(evs[1].event).toBe('message');
  });
});

describe('backoff', () => {
  it('starts at the server retry and doubles to the cap', () => {
    expect(backoff(1, 2000, 500, 5000)).toBe(2000);
    expect(backoff(2, 2000, 500, 5000)).toBe(4000);
    expect(backoff(5, 2000, 500, 5000)).toBe(5000);
    expect(backoff(1, null, 500, 5000)).toBe(500);
  });
});

/** A fake fetch serving scripted SSE bodies, recording the Last-Event-ID each request sent. */
function scriptedFetch(bodies: string[], sent: (string | undefined)[]): typeof fetch {
  let i = 0;
  return (async (_url: unknown, init?: RequestInit) => {
    const h = (init?.headers ?? {}) as Record<string, string>;
    sent.push(h['Last-Event-ID']);
    const body = bodies[Math.min(i++, bodies.length - 1)];
    return new Response(new Blob([body]).stream(), { status: 200, headers: { 'Content-Type': 'text/event-stream' } });
  }) as typeof fetch;
}

describe('EventStream', () => {
  it('resumes with Last-Event-ID after the stream ends, and asks for a resync', async () => {
    const sent: (string | undefined)[] = [];
    const got: SseEvent[] = [];
    const states: StreamState[] = [];
    let resyncs = 0;
    const s = new EventStream({
      url: '/api/v1/events',
      headers: () => ({}),
      onEvent: (e) => got.push(e),
      onState: (st) => states.push(st),
      onReconnect: () => resyncs++,
      fetchImpl: scriptedFetch(['id: 10\nevent: frame\ndata: {}\n\n', 'id: 11\nevent: frame\ndata: {}\n\n'], sent),
      minRetryMs: 1,
      maxRetryMs: 2,
    });
    s.start();
    await new Promise<void>((resolve) => {
      const t = setInterval(() => {
        if (got.length >= 2) {
          clearInterval(t);
          resolve();
        }
      }, 1);
    });
    s.stop();
    expect(sent[0]).toBeUndefined();
    expect(sent[1]).toBe('10');
    expect(got.map((e) => e.id).slice(0, 2)).toEqual(['10', '11']);
    expect(resyncs).toBeGreaterThanOrEqual(1);
    expect(states[0]).toBe('connecting');
    expect(states).toContain('reconnecting');
  });
});
