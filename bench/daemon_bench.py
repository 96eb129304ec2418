#!/usr/bin/python3
"""Daemon measurements for bench/RESULTS.md: ingestion -> published-version latency of a
1920x1080 frame (synthetic generic EXR passes made with oiiotool), and how many concurrent SSE
clients one daemon serves on loopback with every client receiving every event.
Usage: bench/daemon_bench.py [--binary build/proden] [--clients 1000] [--passes 4] [--memory]
(--memory: only the state written per update and the peak RSS of a 1080p frame with features)"""
import argparse
import os
import socket
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "service"))
import harness  # noqa: E402
from harness import Daemon, SseClient, TempRoot, place_atomic  # noqa: E402


def metric_sums(d):
    s, h, body = d.request("GET", "/metrics")
    out = {}
    for line in body.decode().split("\n"):
        if line.startswith("proden_stage_duration_seconds_sum") or line.startswith("proden_stage_duration_seconds_count"):
            name, v = line.rsplit(" ", 1)
            out[name] = float(v)
    return out


def latency(args, root):
    src = os.path.join(root, "src")
    os.makedirs(src)
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
    jid = d.create_job("hd", watch, pattern="{pass}/f_{frame}.exr", spp=4)
    sse = SseClient(d)
    rows = []
    for i, p in enumerate(paths):
        t0 = time.monotonic()
        place_atomic(p, os.path.join(watch, "%02d" % i, "f_0001.exr"))
        sse.events_until(lambda e: e["event"] == "frame" and e["data"]["passes"] == i + 1, 120)
        rows.append(time.monotonic() - t0)
    sums = metric_sums(d)
    d.stop()
    print("1920x1080 generic RGB float EXR passes (%.1f MB each), settle %d ms, 2 workers" %
          (os.path.getsize(paths[0]) / 1e6, settle))
    for i, r in enumerate(rows):
        print("  pass %d: file renamed into the watch dir -> SSE frame event: %.3f s" % (i + 1, r))
    for stage in ("read", "accumulate", "load", "estimate", "pipeline", "persist", "publish"):
        c = sums.get('proden_stage_duration_seconds_count{stage="%s"}' % stage)
        if c:
            print("  stage %-10s mean %.3f s" % (stage, sums['proden_stage_duration_seconds_sum{stage="%s"}' % stage] / c))


def proc_kib(pid, key):
    with open("/proc/%d/status" % pid) as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    return 0


def memory(args, root):
    """Issue 12: bytes of state written per update and the daemon's peak RSS with one resident
    1080p frame with features (generic EXR: RGB, albedo, normal, depth, 10 float channels)."""
    src = os.path.join(root, "msrc")
    os.makedirs(src)
    paths = []
    names = "R,G,B,Albedo.R,Albedo.G,Albedo.B,Normal.X,Normal.Y,Normal.Z,Depth.Z"
    for i in range(args.passes):
        p = os.path.join(src, "p%d.exr" % i)
        subprocess.run(["oiiotool", "--pattern", "noise:type=gaussian:mean=0.5:stddev=0.2:seed=%d"
                        % (i + 1), "1920x1080", "10", "-d", "float", "--chnames", names, "-o", p],
                       check=True)
        paths.append(p)
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
    ap.add_argument("--memory", action="store_true",
                    help="only the state written per update and the peak RSS (issue 12)")
    args = ap.parse_args()
    harness.BINARY = args.binary
    with TempRoot("proden-bench-") as root:
        if args.memory:
            memory(args, root)
            return
        if not args.skip_latency:
            latency(args, root)
        sse_clients(args, root)


if __name__ == "__main__":
    main()
