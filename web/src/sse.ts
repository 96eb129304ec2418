// Server-Sent Events over fetch (so requests can carry the bearer token, which EventSource cannot):
// a spec-following parser (WHATWG HTML, "Server-sent events", 9.2.6) and a reconnecting stream that
// resumes with Last-Event-ID.

export interface SseEvent {
  id: string;
  event: string;
  data: string;
}

/** Incremental parser: feed() text chunks as they arrive, get the complete events. */
export class SseParser {
  lastEventId = '';
  retry: number | null = null;
  private buf = '';
  private data: string[] = [];
  private type = '';
  private sawCR = false;

  feed(chunk: string): SseEvent[] {
    const out: SseEvent[] = [];
    let text = chunk;
    if (this.sawCR && text.startsWith('\n')) text = text.slice(1); // CRLF split across chunks
    this.sawCR = false;
    this.buf += text;
    for (;;) {
      const m = /\r\n|\r|\n/.exec(this.buf);
      if (!m) break;
      if (m[0] === '\r' && m.index === this.buf.length - 1) {
        this.sawCR = true; // maybe the first half of CRLF: the line ends here either way
      }
      const line = this.buf.slice(0, m.index);
      this.buf = this.buf.slice(m.index + m[0].length);
      const ev = this.line(line);
      if (ev) out.push(ev);
    }
    return out;
  }

  private line(line: string): SseEvent | null {
    if (line === '') {
      if (this.data.length === 0) {
        this.type = '';
        return null;
      }
      const ev = { id: this.lastEventId, event: this.type || 'message', data: this.data.join('\n') };
      this.data = [];
      this.type = '';
      return ev;
    }
    if (line.startsWith(':')) return null;
    const colon = line.indexOf(':');
    const field = colon < 0 ? line : line.slice(0, colon);
    let value = colon < 0 ? '' : line.slice(colon + 1);
    if (value.startsWith(' ')) value = value.slice(1);
    if (field === 'data') this.data.push(value);
    else if (field === 'event') this.type = value;
    else if (field === 'id' && !value.includes('\0')) this.lastEventId = value;
    else if (field === 'retry' && /^\d+$/.test(value)) this.retry = Number(value);
    return null;
  }
}

export type StreamState = 'connecting' | 'open' | 'reconnecting' | 'unauthorized' | 'stopped';

export interface StreamOptions {
  url: string;
  headers: () => Record<string, string>;
  onEvent: (e: SseEvent) => void;
  onState: (s: StreamState, detail?: string) => void;
  /** Called when a connection opens after the first: the caller resynchronises its state. */
  onReconnect?: () => void;
  fetchImpl?: typeof fetch;
  minRetryMs?: number;
  maxRetryMs?: number;
}

/** Delay before reconnect attempt `failures` (1, 2, ...): the server's retry, doubling to a cap. */
export function backoff(failures: number, serverRetry: number | null, min: number, max: number): number {
  const base = Math.max(serverRetry ?? min, min);
  return Math.min(max, base * 2 ** Math.max(0, failures - 1));
}

export class EventStream {
  lastEventId = '';
  private abort: AbortController | null = null;
  private stopped = true;
  private connections = 0;
  private wake: (() => void) | null = null;

  constructor(private readonly o: StreamOptions) {}

  start(): void {
    if (!this.stopped) return;
    this.stopped = false;
    void this.loop();
  }

  stop(): void {
    this.stopped = true;
    this.abort?.abort();
    this.wake?.();
    this.o.onState('stopped');
  }

  /** Retry now (e.g. after the token changed) instead of waiting out the back-off. */
  kick(): void {
    this.wake?.();
  }

  private sleep(ms: number): Promise<void> {
    return new Promise((resolve) => {
      const t = setTimeout(done, ms);
      function done() {
        clearTimeout(t);
        resolve();
      }
      this.wake = done;
    });
  }

  private async loop(): Promise<void> {
    const f = this.o.fetchImpl ?? fetch.bind(globalThis);
    const min = this.o.minRetryMs ?? 500;
    const max = this.o.maxRetryMs ?? 5000;
    let failures = 0;
    let serverRetry: number | null = null;
    while (!this.stopped) {
      this.o.onState(this.connections === 0 ? 'connecting' : 'reconnecting');
      this.abort = new AbortController();
      const parser = new SseParser();
      parser.lastEventId = this.lastEventId;
      try {
        const headers: Record<string, string> = { Accept: 'text/event-stream', ...this.o.headers() };
        if (this.lastEventId) headers['Last-Event-ID'] = this.lastEventId;
        const res = await f(this.o.url, { headers, signal: this.abort.signal, cache: 'no-store' });
        if (res.status === 401) {
          this.o.onState('unauthorized');
          failures++;
          await this.sleep(backoff(failures, null, 2000, 30000));
          continue;
        }
        if (!res.ok || !res.body) throw new Error(`HTTP ${res.status}`);
        this.connections++;
        failures = 0;
        this.o.onState('open');
        if (this.connections > 1) this.o.onReconnect?.();
        const reader = res.body.pipeThrough(new TextDecoderStream()).getReader();
        for (;;) {
          const { value, done } = await reader.read();
          if (done) break;
          for (const ev of parser.feed(value)) {
            this.lastEventId = parser.lastEventId;
            this.o.onEvent(ev);
          }
          serverRetry = parser.retry ?? serverRetry;
        }
        throw new Error('stream ended');
      } catch (e) {
        if (this.stopped) break;
        failures++;
        this.o.onState('reconnecting', e instanceof Error ? e.message : String(e));
        await this.sleep(backoff(failures, serverRetry, min, max));
      }
    }
  }
}
