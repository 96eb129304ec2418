"""Peak RSS and time of the daemon making one rendition of a published frame (docs/api.md, the
image endpoint), each from a freshly restarted daemon, so the peak is the rendition's alone.

  PRODEN_BINARY=build/proden PRODEN_SAMPLES_DIR=samples \
      /usr/bin/python3 bench/preview_bench.py STATE_ROOT [REPEATS] [PASS.exr ...]

The first run publishes the passes (default: /tmp/cyc/c1.exr and c4.exr, 1080p Cycles passes
from bench/cycles_frame.py) into STATE_ROOT; later runs reuse it, so two binaries can alternate on
the same published frame. The cache of renditions is emptied after each request."""
import glob
import os
import shutil
import sys
import time
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "service"))
from harness import Daemon, place_atomic

def status(pid):
    r = {}
    for l in open("/proc/%d/status" % pid):
        if l.startswith(("VmHWM", "VmRSS")):
            r[l.split()[0][:-1]] = int(l.split()[1]) // 1024
    return r

root = sys.argv[1]
fresh = not os.path.exists(os.path.join(root, "jid"))
os.makedirs(root, exist_ok=True)
d = Daemon(root, config={"worker_threads": 2})
if fresh:
    d.start()
    watch = os.path.join(d.allowed, "w")
    jid = d.create_job("shot", watch)
    passes = sys.argv[3:] or ["/tmp/cyc/c1.exr", "/tmp/cyc/c4.exr"]
    for i, p in enumerate(passes):
        place_atomic(p, os.path.join(watch, "pass_%02d" % i, "beauty_0001.exr"))
    d.wait_passes(jid, 1, len(passes), timeout=300)
    time.sleep(10)   # idle compression
    d.stop()
    open(os.path.join(root, "jid"), "w").write(jid)
jid = open(os.path.join(root, "jid")).read()
for rep in range(int(sys.argv[2]) if len(sys.argv) > 2 else 1):
    for layer, fmt, size in [("render", "png", 1000 + rep), ("error", "png", 1000 + rep), ("variance", "exr", 0)]:
        d.start(); time.sleep(1.5)
        base = status(d.proc.pid)
        q = "/api/v1/jobs/%s/frames/1/image?format=%s&layer=%s" % (jid, fmt, layer)
        if size: q += "&size=%d" % size
        t0 = time.time(); s, h, b = d.request("GET", q, timeout=300); t = time.time() - t0
        after = status(d.proc.pid)
        print("%-8s %s: %d, %.2f s, peak +%d MB" % (layer, fmt, s, t, after["VmHWM"] - base["VmHWM"]), flush=True)
        d.stop()
        # the cache keeps renditions: drop them so the next start makes them again
        for c in glob.glob(os.path.join(d.state, "jobs", "*", "cache")):
            shutil.rmtree(c)
