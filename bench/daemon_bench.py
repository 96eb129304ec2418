#!/usr/bin/python3
"""Daemon measurements for bench/RESULTS.md: ingestion -> published-version latency of a
1920x1080 frame (synthetic generic EXR passes made with oiiotool), and how many concurrent SSE
clients one daemon serves on loopback with every client receiving every event.
Usage: bench/daemon_bench.py [--binary build/proden] [--clients 1000] [--passes 4]"""
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
    args = ap.parse_args()
    harness.BINARY = args.binary
    with TempRoot("proden-bench-") as root:
        if not args.skip_latency:
            latency(args, root)
        sse_clients(args, root)


if __name__ == "__main__":
    main()
