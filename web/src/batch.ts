// Batches view updates to one per animation frame: SSE can bring 50+ events a second, but the DOM
// is touched once per frame, and only for what changed (never the whole grid).

export class FrameBatcher<K> {
  private dirty = new Set<K>();
  private pending = false;

  constructor(
    private readonly flush: (keys: Set<K>) => void,
    private readonly raf: (cb: () => void) => unknown = (cb) => requestAnimationFrame(cb),
  ) {}

  mark(key: K): void {
    this.dirty.add(key);
    if (this.pending) return;
    this.pending = true;
    this.raf(() => this.run());
  }

  private run(): void {
    this.pending = false;
    const keys = this.dirty;
    this.dirty = new Set();
    if (keys.size) this.flush(keys);
  }
}
