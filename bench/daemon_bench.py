#!/usr/bin/python3
"""Daemon measurements for bench/RESULTS.md: ingestion -> published-version latency of a
1920x1080 frame (synthetic generic EXR passes made with oiiotool), and how many concurrent SSE
clients one daemon serves on loopback with every client receiving every event.
Usage: bench/daemon_bench.py [--binary build/proden] [--clients 1000] [--passes 4] [--memory]
       bench/daemon_bench.py --latency-only [--features] [--gap S] [--compression C] [--json J]
       bench/daemon_bench.py --lag [--frames 10] [--rates 30,60,120,240] [--seconds 120] --png P
(--memory: only the state written per update and the peak RSS of a 1080p frame with features;
 --lag: only the lag from a pass landing to its version, 10 frames at 1080p, for a rate sweep)"""
import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import threading
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "service"))
import harness  # noqa: E402
from harness import Daemon, SseClient, TempRoot, place_atomic, wait_until  # noqa: E402


def metric_sums(d):
    s, h, body = d.request("GET", "/metrics")
    out = {}
    for line in body.decode().split("\n"):
        if line.startswith("proden_stage_duration_seconds_sum") or line.startswith("proden_stage_duration_seconds_count"):
            name, v = line.rsplit(" ", 1)
            out[name] = float(v)
    return out


def stage_means(d):
    sums = metric_sums(d)
    out = {}
    for stage in ("read", "accumulate", "load", "estimate", "pipeline", "denoise", "cross_validation",
                  "mix", "ttest", "persist", "publish"):
        c = sums.get('proden_stage_duration_seconds_count{stage="%s"}' % stage)
        if c:
            out[stage] = (sums['proden_stage_duration_seconds_sum{stage="%s"}' % stage] / c, int(c))
    return out


def latency(args, root):
    src = os.path.join(root, "src")
    os.makedirs(src)
    if args.features:  # the lag bench's 10-channel passes: the default pipeline's 27-channel output
        paths = make_feature_passes(src, args.passes)
    else:
        paths = []
        for i in range(args.passes):
            p = os.path.join(src, "p%d.exr" % i)
            subprocess.run(["oiiotool", "--pattern", "noise:type=gaussian:mean=0.5:stddev=0.2:seed=%d" % (i + 1),
                            "1920x1080", "3", "-d", "float", "--chnames", "R,G,B", "-o", p], check=True)
            paths.append(p)
    settle = 250
    d = Daemon(os.path.join(root, "lat"), config={"watch": {"settle_ms": settle, "tick_ms": 25,
                                                             "poll_interval_ms": 2000}})
    os.makedirs(d.root, exist_ok=True)
    d.start()
    watch = os.path.join(d.allowed, "w")
    extra = {"output": {"dir": os.path.join(d.allowed, "out_hd"),
                        "compression": args.compression}} if args.compression else {}
    jid = d.create_job("hd", watch, pattern="{pass}/f_{frame}.exr", spp=4, **extra)
    sse = SseClient(d)
    rows = []
    for i, p in enumerate(paths):
        if i and args.gap:  # an idle daemon between passes (a farm it keeps up with)
            time.sleep(args.gap)
        t0 = time.monotonic()
        place_atomic(p, os.path.join(watch, "%02d" % i, "f_0001.exr"))
        sse.events_until(lambda e: e["event"] == "frame" and e["data"]["passes"] == i + 1, 120)
        rows.append(time.monotonic() - t0)
    time.sleep(args.gap)
    stages = stage_means(d)
    compressed = harness.metric(d, "proden_publish_compressed_later_total")
    huge_pages = d.huge_pages()
    d.stop()
    print("1920x1080 generic %s float EXR passes (%.1f MB each), settle %d ms, 2 workers, "
          "%.0f s idle between passes, output.compression %s" %
          ("10-channel (RGB, albedo, normal, depth)" if args.features else "RGB",
           os.path.getsize(paths[0]) / 1e6, settle, args.gap, args.compression or "(default)"))
    for i, r in enumerate(rows):
        print("  pass %d: file renamed into the watch dir -> SSE frame event: %.3f s" % (i + 1, r))
    for stage, (mean, _) in stages.items():
        print("  stage %-10s mean %.3f s" % (stage, mean))
    print("  versions compressed later (proden_publish_compressed_later_total): %.0f" % compressed)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"latency_s": rows, "stages": {k: v[0] for k, v in stages.items()},
                       "compressed_later": compressed, "gap_s": args.gap,
                       "features": args.features, "compression": args.compression,
                       "huge_pages": huge_pages}, f, indent=1)


FEATURE_CHANNELS = "R,G,B,Albedo.R,Albedo.G,Albedo.B,Normal.X,Normal.Y,Normal.Z,Depth.Z"


def make_feature_passes(src, count, size="1920x1080"):
    """`count` distinct generic float EXR passes with features (10 channels), seeds 1..count."""
    os.makedirs(src, exist_ok=True)
    paths = []
    for i in range(count):
        p = os.path.join(src, "p%03d.exr" % i)
        if not os.path.exists(p):
            subprocess.run(["oiiotool", "--pattern", "noise:type=gaussian:mean=0.5:stddev=0.2:seed=%d"
                            % (i + 1), size, "10", "-d", "float", "--chnames", FEATURE_CHANNELS,
                            "-o", p], check=True)
        paths.append(p)
    return paths


def place_link(src, dst):
    """Places src at dst as a renderer does (temp name, then rename), by hard link: no copy."""
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    tmp = os.path.join(os.path.dirname(dst), "." + os.path.basename(dst) + ".tmp")
    os.link(src, tmp)
    os.rename(tmp, dst)


def proc_kib(pid, key):
    with open("/proc/%d/status" % pid) as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    return 0


def memory(args, root):
    """Issue 12: bytes of state written per update and the daemon's peak RSS with one resident
    1080p frame with features (generic EXR: RGB, albedo, normal, depth, 10 float channels)."""
    paths = make_feature_passes(os.path.join(root, "msrc"), args.passes)
    names = FEATURE_CHANNELS
    d = Daemon(os.path.join(root, "mem"), config={"watch": {"settle_ms": 250, "tick_ms": 25,
                                                             "poll_interval_ms": 2000}})
    os.makedirs(d.root, exist_ok=True)
    d.start()
    pid = d.proc.pid
    base_hwm = proc_kib(pid, "VmHWM")
    watch = os.path.join(d.allowed, "w")
    jid = d.create_job("mem", watch, pattern="{pass}/f_{frame}.exr", spp=4)
    sse = SseClient(d)
    state = os.path.join(d.state, "jobs", jid, "frames", "1.state")
    print("1920x1080 generic float EXR passes with features (%s; %.1f MB each), one frame" %
          (names, os.path.getsize(paths[0]) / 1e6))
    print("  daemon at start: VmHWM %.0f MiB" % (base_hwm / 1024))
    for i, p in enumerate(paths):
        place_atomic(p, os.path.join(watch, "%02d" % i, "f_0001.exr"))
        sse.events_until(lambda e: e["event"] == "frame" and e["data"]["passes"] == i + 1, 300)
        print("  pass %d: state file %.1f MB, VmHWM %.0f MiB, VmRSS %.0f MiB" % (
            i + 1, os.path.getsize(state) / 1e6, proc_kib(pid, "VmHWM") / 1024,
            proc_kib(pid, "VmRSS") / 1024))
    sums = metric_sums(d)
    d.stop()
    c = sums.get('proden_stage_duration_seconds_count{stage="persist"}')
    if c:
        print("  persist: mean %.3f s per update" %
              (sums['proden_stage_duration_seconds_sum{stage="persist"}'] / c))


class FrameEventLog(threading.Thread):
    """Reads the SSE stream in the background and keeps (monotonic time, frame, passes) of every
    frame event."""

    def __init__(self, daemon):
        super().__init__(daemon=True)
        self.sse = SseClient(daemon, timeout=3600)
        self.events = []
        self.lock = threading.Lock()
        self.stop = False

    def run(self):
        self.sse.sock.settimeout(1.0)
        while not self.stop:
            try:
                e = self.sse.next_event()
            except (socket.timeout, TimeoutError):
                continue
            except (EOFError, OSError):
                return
            if e["event"] == "frame":
                with self.lock:
                    self.events.append((time.monotonic(), e["data"]["frame"], e["data"]["passes"]))

    def published(self, frame):
        """Highest pass count published for `frame` so far."""
        with self.lock:
            return max([p for _, f, p in self.events if f == frame] or [0])

    def first_at(self, frame, passes):
        with self.lock:
            for t, f, p in self.events:
                if f == frame and p >= passes:
                    return t
        return None


def percentile(xs, q):
    xs = sorted(xs)
    if not xs:
        return float("nan")
    k = (len(xs) - 1) * q
    lo = int(k)
    hi = min(lo + 1, len(xs) - 1)
    return xs[lo] + (xs[hi] - xs[lo]) * (k - lo)


def lag_daemon(root, name, resident=None, compression=None):
    # The shipped watch settings (settle 1 s, tick 200 ms, full scan every 2 s): the lag a farm sees.
    config = {"watch": {}}
    if resident is not None:
        config["max_resident_frames"] = resident
    d = Daemon(os.path.join(root, name), config=config)
    os.makedirs(d.root, exist_ok=True)
    d.start()
    watch = os.path.join(d.allowed, "w")
    # output.history 0: only the latest image per frame stays on disk (the bench's disk budget).
    output = {"dir": os.path.join(d.allowed, "out"), "history": 0}
    if compression:
        output["compression"] = compression
    jid = d.create_job(name, watch, pattern="{pass}/f_{frame}.exr", spp=4, output=output)
    return d, watch, jid


def lag_reference(root, paths, resident=None, compression=None):
    """One isolated update: a single pass into an idle daemon, rename -> SSE frame event."""
    d, watch, _ = lag_daemon(root, "ref", resident, compression)
    log = FrameEventLog(d)
    log.start()
    rows = []
    for i in range(2):
        t0 = time.monotonic()
        place_link(paths[i], os.path.join(watch, "%03d" % i, "f_0001.exr"))
        wait_until(lambda: log.first_at(1, i + 1), 600, interval=0.02, what="reference update")
        rows.append(log.first_at(1, i + 1) - t0)
    stages = stage_means(d)
    huge_pages = d.huge_pages()
    log.stop = True
    d.stop()
    shutil.rmtree(d.root, ignore_errors=True)
    return rows, stages, huge_pages


def lag_run(root, paths, frames, rate, seconds, drain_s, resident=None, compression=None):
    """Places passes round-robin over `frames` frames at `rate` passes/min for `seconds`, then
    waits up to `drain_s` for the last to be published. Returns the per-pass lags (None: not
    published within the drain), the stage means and the worker utilisation."""
    d, watch, _ = lag_daemon(root, "r%d" % rate, resident, compression)
    log = FrameEventLog(d)
    log.start()
    n = int(rate * seconds / 60)
    placed = []  # (time, frame, passes of that frame after this one)
    t_start = time.monotonic()
    busy0 = worker_busy(d)
    for k in range(n):
        due = t_start + k * 60.0 / rate
        now = time.monotonic()
        if due > now:
            time.sleep(due - now)
        frame, index = k % frames + 1, k // frames
        t = time.monotonic()
        place_link(paths[index], os.path.join(watch, "%03d" % index, "f_%04d.exr" % frame))
        placed.append((t, frame, index + 1))
    t_end = time.monotonic()
    backlog_at_end = sum(1 for t, f, p in placed if log.published(f) < p)
    last = {}
    for t, f, p in placed:
        last[f] = max(last.get(f, 0), p)
    deadline = time.monotonic() + drain_s
    while time.monotonic() < deadline and any(log.published(f) < p for f, p in last.items()):
        time.sleep(0.1)
    busy = (worker_busy(d) - busy0) / (time.monotonic() - t_start)
    lags = []
    for t, f, p in placed:
        r = log.first_at(f, p)
        lags.append(None if r is None else r - t)
    versions = len(log.events)
    stages = stage_means(d)
    log.stop = True
    d.stop()
    shutil.rmtree(d.root, ignore_errors=True)
    return {"rate": rate, "passes": n, "placed_s": t_end - t_start, "lags": lags,
            "times": [t - t_start for t, _, _ in placed], "backlog_at_end": backlog_at_end,
            "versions": versions, "stages": stages, "busy": busy}


def worker_busy(d):
    s, h, body = d.request("GET", "/metrics")
    for line in body.decode().split("\n"):
        if line.startswith("proden_worker_busy_seconds_total"):
            return float(line.rsplit(" ", 1)[1])
    return 0.0


def lag(args, root):
    """Issue 12: lag from a pass landing to its version being published, 10 frames at 1080p with
    features, for a sweep of farm rates; and the rate beyond which the lag grows without bound."""
    rates = [int(r) for r in args.rates.split(",")]
    per_frame = max(2, -(-max(rates) * args.seconds // (60 * args.frames)))
    t0 = time.monotonic()
    paths = make_feature_passes(os.path.join(args.lag_src or root, "lagsrc"), per_frame)
    print("1920x1080 generic float EXR passes with features (%s; %.1f MB each), %d distinct "
          "(made in %.0f s), placed by hard link + rename" % (
              FEATURE_CHANNELS, os.path.getsize(paths[0]) / 1e6, len(paths), time.monotonic() - t0))
    ref, ref_stages, huge_pages = lag_reference(root, paths, args.resident, args.compression)
    update = ref[1]
    print("reference: one pass into an idle daemon, rename -> frame event: first %.2f s, second "
          "%.2f s (the update time U below is the second)" % (ref[0], ref[1]))
    print("  stages: " + ", ".join("%s %.2f s" % (k, v[0]) for k, v in ref_stages.items()))
    results = []
    for rate in rates:
        r = lag_run(root, paths, args.frames, rate, args.seconds, args.drain, args.resident,
                    args.compression)
        done = [x for x in r["lags"] if x is not None]
        third = max(1, len(r["lags"]) // 3)
        first = [x for x in r["lags"][:third] if x is not None]
        lastt = [x if x is not None else float("inf") for x in r["lags"][-third:]]
        r.update({"update_s": update, "p50": percentile(done, 0.5), "p99": percentile(done, 0.99),
                  "max": max(done) if done else float("nan"), "unpublished": len(r["lags"]) - len(done),
                  "first_third_p50": percentile(first, 0.5), "last_third_p50": percentile(lastt, 0.5)})
        results.append(r)
        print("rate %d passes/min over %d frames: %d passes in %.0f s; lag p50 %.1f s, p99 %.1f s, "
              "max %.1f s (= %.2f U); first/last third p50 %.1f / %.1f s; %d frame events; "
              "backlog at the last placement %d; unpublished after %d s %d; workers busy %.2f of 2" % (
                  rate, args.frames, r["passes"], r["placed_s"], r["p50"], r["p99"], r["max"],
                  r["max"] / update, r["first_third_p50"], r["last_third_p50"], r["versions"],
                  r["backlog_at_end"], args.drain, r["unpublished"], r["busy"]))
        print("  stages: " + ", ".join("%s %.2f s x%d" % (k, v[0], v[1]) for k, v in r["stages"].items()))
        sys.stdout.flush()
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"reference": ref, "reference_stages": ref_stages, "frames": args.frames,
                       "resident": args.resident, "compression": args.compression,
                       "seconds": args.seconds, "huge_pages": huge_pages, "runs": results}, f)
    if args.png:
        lag_plot(results, update, args.png, load_baseline(args), args.label, args.baseline_label)


def load_baseline(args):
    """The --baseline run's JSON, or None."""
    if not args.baseline:
        return None
    with open(args.baseline) as f:
        return json.load(f)


def lag_plot(results, update, path, base=None, label="", base_label="baseline"):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.5))
    for r in results:
        xs = [t for t, l in zip(r["times"], r["lags"]) if l is not None]
        ys = [l for l in r["lags"] if l is not None]
        a.plot(xs, ys, ".", ms=3, label="%d passes/min" % r["rate"])
    a.axhline(2 * update, color="k", ls="--", lw=1, label="2 x update time")
    a.set_xlabel("pass placed at (s)")
    a.set_ylabel("lag to its version (s)")
    a.set_title("lag of each pass (10 frames, 1080p + features)")
    a.legend(fontsize=8)
    rates = [r["rate"] for r in results]
    for key, colour in (("p50", "C0"), ("p99", "C1"), ("max", "C2")):
        b.plot(rates, [r[key] for r in results], "o-", color=colour,
               label=(label + " " if label else "") + key)
        if base:
            b.plot([r["rate"] for r in base["runs"]], [r[key] for r in base["runs"]], "o:",
                   color=colour, alpha=0.6, label=base_label + " " + key)
    b.axhline(2 * update, color="k", ls="--", lw=1, label="2 x update time")
    b.set_xlabel("farm rate (passes/min, all frames)")
    b.set_ylabel("lag (s)")
    b.set_title("lag against rate")
    b.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def sse_clients(args, root):
    # All clients come from one loopback address: lift the per-client and total stream limits
    # (docs/api.md, "Security and limits") above the number measured.
    n = args.clients
    d = Daemon(os.path.join(root, "sse"), config={"limits": {
        "max_sse_per_client": n, "max_sse_streams": n, "max_connections": max(4096, 2 * n)}})
    os.makedirs(d.root, exist_ok=True)
    d.start()
    clients = []
    t0 = time.monotonic()
    try:
        for _ in range(args.clients):
            clients.append(SseClient(d, timeout=30))
    except OSError as e:
        print("  connect failed after %d clients: %s" % (len(clients), e))
    connect_s = time.monotonic() - t0
    ok = sum(1 for c in clients if "200" in c.status_line)
    t0 = time.monotonic()
    jid = d.create_job("ssebench")
    got = 0
    for c in clients:
        try:
            e = c.events_until(lambda e: e["event"] == "job" and e["data"]["job"] == jid, 30)
            got += 1
        except Exception as ex:  # noqa: BLE001
            print("  client failed: %s" % ex)
    fanout_s = time.monotonic() - t0
    s, h, body = d.request("GET", "/metrics")
    gauge = [l for l in body.decode().split("\n") if l.startswith("proden_sse_clients ")]
    errs = [l for l in body.decode().split("\n") if l.startswith("proden_errors_total")]
    live = d.json("GET", "/livez")[0]
    for c in clients:
        c.close()
    d.stop()
    print("SSE: %d clients connected (%.2f s), %d/%d received the event (%.2f s), %s, livez %d"
          % (ok, connect_s, got, len(clients), fanout_s, gauge[0] if gauge else "?", live))
    print("  errors: %s" % (errs or "none"))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--binary", default="build/proden")
    ap.add_argument("--clients", type=int, default=1000)
    ap.add_argument("--passes", type=int, default=4)
    ap.add_argument("--skip-latency", action="store_true")
    ap.add_argument("--latency-only", action="store_true", help="no SSE client sweep")
    ap.add_argument("--features", action="store_true",
                    help="latency: 10-channel passes with features (the default pipeline's "
                    "27-channel output) instead of RGB")
    ap.add_argument("--gap", type=float, default=0.0,
                    help="latency: seconds the daemon stays idle between passes")
    ap.add_argument("--memory", action="store_true",
                    help="only the state written per update and the peak RSS (issue 12)")
    ap.add_argument("--lag", action="store_true",
                    help="only the lag curve: pass landing -> its version published (issue 12)")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--rates", default="30,60,120,240", help="passes/min over all frames")
    ap.add_argument("--seconds", type=int, default=120, help="placement time per rate")
    ap.add_argument("--drain", type=int, default=300, help="wait for the last version (s)")
    ap.add_argument("--resident", type=int,
                    help="the daemon's max_resident_frames (default: the shipped one, 64, with the shipped "
                         "memory budget, max_resident_bytes 0)")
    ap.add_argument("--compression", help="the jobs' output.compression (default: the daemon's)")
    ap.add_argument("--lag-src", help="keep the generated passes here (reused if present)")
    ap.add_argument("--json")
    ap.add_argument("--png")
    ap.add_argument("--baseline", help="a --json of an earlier binary, drawn dotted in the PNG")
    ap.add_argument("--label", default="", help="this binary's name in the PNG")
    ap.add_argument("--baseline-label", default="baseline")
    ap.add_argument("--replot", help="only redraw --png from this --json")
    args = ap.parse_args()
    harness.BINARY = args.binary
    with TempRoot("proden-bench-") as root:
        if args.replot:
            with open(args.replot) as f:
                run = json.load(f)
            lag_plot(run["runs"], run["reference"][1], args.png, load_baseline(args), args.label,
                     args.baseline_label)
            return
        if args.lag:
            lag(args, root)
            return
        if args.memory:
            memory(args, root)
            return
        if not args.skip_latency:
            latency(args, root)
        if not args.latency_only:
            sse_clients(args, root)


if __name__ == "__main__":
    main()
