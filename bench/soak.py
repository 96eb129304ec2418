#!/usr/bin/python3
"""Soak test of `proden serve` (issue 11, "Done when"): the real Release daemon on loopback for
SOAK_MINUTES with 200 SSE clients connected the whole time, 20 passes a second across 10 frames of
two jobs (half uploaded with PUT, half written atomically into the jobs' watched directories), and
a `kill -9` of the daemon every 3 minutes followed at once by a restart on the same state
directory. It checks, and exits non-zero on any violation:

- 0 errors: no HTTP 5xx or unexpected 4xx, no `error` event, no warning or error in the daemon's
  log, no exit of the daemon other than the deliberate kills, no SSE disconnect other than at a
  kill, no upload that fails other than at a kill;
- resident memory: after warm-up, under 10 % growth, comparing like with like (the same part of
  each restart epoch; see rss_analysis);
- every pass counted exactly once: each frame's `pass_list` is exactly the set of passes sent (no
  duplicate, none lost, none quarantined), and every SSE client saw each frame's versions strictly
  increasing (event ids too), every version while it stayed connected, and the final version of
  every frame after resuming with Last-Event-ID.

Passes are crops of samples/renders/cornell (made once with oiiotool, uncompressed), each varied
per pass (its beauty channels scaled per pixel by random factors) so that every pass has distinct
content. Standard library only, plus matplotlib for the optional RSS plot.

Usage: bench/soak.py [--minutes 30] [--binary build/proden] [--report bench/results/soak.md]
       [--png bench/results/soak_rss.png] [--json out.json]   (`make soak`, SOAK_MINUTES)"""
import argparse
import array
import hashlib
import http.client
import json
import operator
import os
import queue
import random
import re
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
import traceback

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "service"))
import harness  # noqa: E402
from harness import Daemon, SseClient, TempRoot, place_atomic, wait_until  # noqa: E402
from hostile_support import proc_status_mib  # noqa: E402

WATCH_PATTERN = "f{frame}/{pass}.exr"
# The example deployment's watcher settings (deploy/proden.example.json), not the tests' fast ones.
WATCH = {"poll_interval_ms": 2000, "settle_ms": 1000, "tick_ms": 200, "max_attempts": 3}
GROWTH_LIMIT = 0.10
CONNECTION_ERRORS = (OSError, EOFError, http.client.HTTPException)


# ---------------------------------------------------------------------------------------------
# Pass files


class PassTemplate:
    """An uncompressed scanline OpenEXR pass (a crop written by oiiotool) whose beauty channels
    (`*Combined.R/G/B`, or `R/G/B`) are rewritten per pass. Layout after OpenEXR's "File Layout":
    magic, version, attributes (name, type, size, value) up to an empty name, the line offset
    table, then per scanline its y, its byte count and the channels in header order."""

    def __init__(self, path):
        with open(path, "rb") as f:
            self.data = f.read()
        d = self.data
        assert d[:4] == b"\x76\x2f\x31\x01", path
        pos, attrs = 8, {}
        while d[pos] != 0:
            name_end = d.index(b"\0", pos)
            type_end = d.index(b"\0", name_end + 1)
            size = struct.unpack_from("<I", d, type_end + 1)[0]
            attrs[d[pos:name_end].decode()] = d[type_end + 5:type_end + 5 + size]
            pos = type_end + 5 + size
        pos += 1
        assert attrs["compression"] == b"\0", path + ": not uncompressed"
        x0, y0, x1, y1 = struct.unpack("<iiii", attrs["dataWindow"])
        self.width, self.height = x1 - x0 + 1, y1 - y0 + 1
        channels, c = [], attrs["channels"]
        i = 0
        while c[i] != 0:
            e = c.index(b"\0", i)
            ptype = struct.unpack_from("<i", c, e + 1)[0]
            channels.append((c[i:e].decode(), ptype))
            i = e + 17
        offsets = struct.unpack_from("<%dQ" % self.height, d, pos)
        self.ranges = []  # (start, end) of each beauty channel's floats, per scanline
        for off in offsets:
            at = off + 8
            for name, ptype in channels:
                n = self.width * (2 if ptype == 1 else 4)
                if name in ("R", "G", "B") or name.endswith(("Combined.R", "Combined.G", "Combined.B")):
                    assert ptype == 2, "%s: %s is not FLOAT" % (path, name)
                    self.ranges.append((at, at + n))
                at += n
        assert self.ranges, path + ": no beauty channels"

    def vary(self, rng, pool):
        """A new pass: every beauty value scaled by a factor from `pool` at random offsets."""
        buf = bytearray(self.data)
        w = self.width
        for s, e in self.ranges:
            k = rng.randrange(len(pool) - w)
            buf[s:e] = array.array("f", map(operator.mul, array.array("f", buf[s:e]),
                                            pool[k:k + w])).tobytes()
        return bytes(buf)


def make_templates(samples, frames, size, scratch):
    """Per frame, the 8 Cornell passes cropped at that frame's own window (uncompressed): one
    oiiotool run per source pass writes its crops for every frame."""
    full = 128
    out = {key: [] for key in frames}
    procs = []
    for i in range(8):
        cmd = ["oiiotool", os.path.join(samples, "renders", "cornell", "pass_%02d.exr" % i)]
        for n, key in enumerate(frames):
            x = (n * 17) % (full - size + 1)
            y = (n * 29) % (full - size + 1)
            p = os.path.join(scratch, "t_%d_%d_%d.exr" % (key[0], key[1], i))
            cmd += ["--dup", "--cut", "%dx%d+%d+%d" % (size, size, x, y), "--compression", "none",
                    "-o", p, "--pop"]
            out[key].append(p)
        procs.append(subprocess.Popen(cmd))
    for p in procs:
        assert p.wait() == 0, "oiiotool failed"
    return {k: [PassTemplate(p) for p in v] for k, v in out.items()}


# ---------------------------------------------------------------------------------------------
# The run


class Soak:
    def __init__(self, args, root):
        self.args = args
        self.root = root
        self.lock = threading.Lock()
        self.errors = []          # every violation, as text
        self.error_counts = {}    # the same, counted by category
        self.stopping = False
        self.sending = True
        self.kills_started = 0    # raised before each SIGKILL: a connection that ends after it
        self.down = False         # between a SIGKILL and the restart
        self.t0 = None
        self.epoch_starts = []    # run time at which each epoch's daemon was listening
        self.kill_times = []
        self.restart_s = []       # SIGKILL -> listening again
        self.rss = []             # (run time, epoch, MiB)
        self.loads = []           # (run time, 1-min load average)
        self.backlog = []         # (run time, passes sent - passes counted)
        self.metrics_last = {}    # epoch -> last /metrics sample
        self.queue_depth_max = 0
        self.sent = {}            # (job index, frame) -> {pass name: "watch"|"upload"}
        self.sent_order = []      # every pass sent (for the counts)
        self.hashes = set()
        self.upload_q = queue.Queue()
        self.upload_lat = []
        self.upload_retries = 0
        self.error_events = {}    # event id -> data (each seen by many clients)
        self.clients = []
        self.daemon = None
        self.jobs = []            # job ids, by index
        self.final = {}           # (job index, frame) -> its final version, passes, history
        self.history = {}         # (job id, frame) -> the versions in its history
        self.missed = []          # (job id, frame, version) some client never saw (at kills)
        self.missed_logged = 0
        self.t_load0 = self.t_load_end = 0.0
        self.drain_s = 0.0
        self.log_lines = 0

    # ---- bookkeeping ----
    def now(self):
        return time.monotonic() - self.t0

    def fail(self, category, text):
        with self.lock:
            self.error_counts[category] = self.error_counts.get(category, 0) + 1
            if len(self.errors) < 200:
                self.errors.append("[%.1f s] %s: %s" % (self.now(), category, text))

    # ---- daemon ----
    def start_daemon(self):
        a = self.args
        cfg = {"watch": dict(WATCH), "log_level": "info"}
        if a.workers:
            cfg["worker_threads"] = a.workers
        self.daemon = Daemon(self.root, config=cfg)
        self.daemon.start()
        self.epoch_starts.append(0.0)

    def kill_and_restart(self):
        d = self.daemon
        with self.lock:
            self.kills_started += 1
            self.down = True
        t = self.now()
        self.kill_times.append(t)
        rc = d.kill9()
        if rc != -9:
            self.fail("crash", "daemon exited with %s before the SIGKILL landed" % rc)
        d.start(timeout=120)
        self.restart_s.append(self.now() - t)
        self.epoch_starts.append(self.now())
        with self.lock:
            self.down = False

    def check_alive(self):
        d = self.daemon
        rc = d.proc.poll() if d.proc else None
        if rc is not None and not self.down:
            self.fail("crash", "daemon exited by itself with %s; log:\n%s" % (rc, d.read_log()))
            with self.lock:
                self.down = True
            d.stop()
            d.start(timeout=120)
            self.epoch_starts.append(self.now())
            with self.lock:
                self.down = False

    def create_jobs(self):
        d = self.daemon
        for j in range(self.args.jobs):
            name = "soak%d" % j
            for f in range(1, self.args.frames // self.args.jobs + 1):
                os.makedirs(os.path.join(d.allowed, name + "_renders", "f%04d" % f), exist_ok=True)
            jid = d.create_job(name, os.path.join(d.allowed, name + "_renders"), pattern=WATCH_PATTERN,
                               pipeline={"denoiser": self.args.denoiser})
            self.jobs.append(jid)

    # ---- senders ----
    def sender(self, templates):
        """Sends pass after pass at the set rate, frame after frame, alternating watched files and
        uploads within each frame; keeps going while the daemon is down."""
        a = self.args
        rng = random.Random(a.seed)
        pool = array.array("f", (max(0.25, rng.gauss(1.0, 0.15)) for _ in range(1 << 16)))
        keys = sorted(templates)
        counter = {k: 0 for k in keys}
        scratch = os.path.join(self.root, "scratch.exr")
        i = 0
        period = 1.0 / a.rate
        while self.sending:
            due = self.t_send0 + i * period
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
                if not self.sending:
                    break
            key = keys[i % len(keys)]
            n = counter[key]
            counter[key] += 1
            data = templates[key][n % len(templates[key])].vary(rng, pool)
            h = hashlib.sha256(data).digest()
            if h in self.hashes:
                raise AssertionError("two passes with the same content: the generator is broken")
            self.hashes.add(h)
            watched = n % 2 == 0
            name = ("w%06d" if watched else "u%06d") % n
            with self.lock:
                self.sent.setdefault(key, {})[name] = "watch" if watched else "upload"
                self.sent_order.append(key)
            if watched:
                with open(scratch, "wb") as f:
                    f.write(data)
                job_name = "soak%d" % key[0]
                place_atomic(scratch, os.path.join(self.daemon.allowed, job_name + "_renders",
                                                   "f%04d" % key[1], name + ".exr"))
            else:
                self.upload_q.put((key, name, data, time.monotonic()))
            i += 1

    def uploader(self):
        while True:
            item = self.upload_q.get()
            if item is None:
                return
            key, name, data, t_sent = item
            path = "/api/v1/jobs/%s/frames/%d/passes/%s" % (self.jobs[key[0]], key[1], name)
            interrupted = False
            while True:
                kills = self.kills_started
                try:
                    status, _, body = self.daemon.request("PUT", path, data, timeout=120)
                except CONNECTION_ERRORS as e:
                    if not (self.down or self.kills_started != kills):
                        time.sleep(0.5)  # the kill may be starting; decide after a moment
                        if not (self.down or self.kills_started != kills):
                            self.fail("upload_connection", "%s: %r" % (path, e))
                    interrupted = True
                    with self.lock:
                        self.upload_retries += 1
                    time.sleep(0.2)
                    continue
                try:
                    st = json.loads(body).get("status")
                except ValueError:
                    st = None
                if status == 202 and st == "queued":
                    break
                if status == 200 and st == "ingested" and interrupted:
                    break  # an earlier attempt was stored and counted before its answer was lost
                self.fail("http_%dxx" % (status // 100) if status >= 500 else "http_unexpected",
                          "PUT %s -> %d %s" % (path, status, body[:300]))
                if status >= 500:
                    time.sleep(1.0)
                    interrupted = True
                    continue
                break
            with self.lock:
                self.upload_lat.append(time.monotonic() - t_sent)

    # ---- samplers ----
    def sampler(self):
        last_metrics = 0.0
        while not self.stopping:
            t = self.now()
            d = self.daemon
            proc = d.proc
            if proc is not None and not self.down:
                try:
                    mib = proc_status_mib(proc.pid, "VmRSS")
                    if mib > 0:
                        self.rss.append((t, len(self.epoch_starts) - 1, mib))
                except OSError:
                    pass
            if t - last_metrics >= 5.0 and not self.down:
                last_metrics = t
                self.loads.append((t, os.getloadavg()[0]))
                self.sample_daemon(t)
            time.sleep(1.0)

    def sample_daemon(self, t):
        d = self.daemon
        epoch = len(self.epoch_starts) - 1
        try:
            s, _, body = d.request("GET", "/metrics", timeout=30)
            counted = 0
            for jid in self.jobs:
                counted += sum(f["passes"] for f in d.frames(jid).values())
        except CONNECTION_ERRORS:
            return  # a kill; the next sample comes from the new daemon
        except AssertionError as e:
            self.fail("http_unexpected", str(e))
            return
        m = {}
        for line in body.decode().split("\n"):
            if line and not line.startswith("#"):
                k, _, v = line.rpartition(" ")
                try:
                    m[k] = float(v)
                except ValueError:
                    pass
        if epoch == len(self.epoch_starts) - 1:
            self.metrics_last[epoch] = m
        self.queue_depth_max = max(self.queue_depth_max, m.get("proden_queue_depth", 0))
        with self.lock:
            sent = len(self.sent_order)
        self.backlog.append((t, sent - counted))

    # ---- the run ----
    def run(self):
        a = self.args
        self.t0 = time.monotonic()
        templates = make_templates(a.samples, self.frame_keys(), a.size, self.root)
        print("soak: %d frames x 8 pass templates (%dx%d Cornell crops), %.1f s" %
              (len(templates), a.size, a.size, self.now()), file=sys.stderr)
        self.t0 = time.monotonic()
        self.start_daemon()
        self.create_jobs()
        for i in range(a.clients):
            c = SseWatcher(self, i)
            c.start()
            self.clients.append(c)
        wait_until(lambda: all(c.connects > 0 for c in self.clients), 60, 0.1,
                   "%d SSE clients to connect" % a.clients)
        threads = [threading.Thread(target=self.sampler, daemon=True)]
        threads += [threading.Thread(target=self.uploader, daemon=True) for _ in range(a.uploaders)]
        for t in threads:
            t.start()
        self.t_send0 = time.monotonic()
        self.t_load0 = self.now()
        sender = threading.Thread(target=self.sender, args=(templates,), daemon=True)
        sender.start()
        end = self.t_load0 + a.minutes * 60.0
        next_kill = self.t_load0 + a.kill_every
        while self.now() < end:
            time.sleep(0.25)
            self.check_alive()
            if not sender.is_alive():
                self.fail("harness", "the sender stopped")
                break
            if self.now() >= next_kill and next_kill < end - 1.0:
                self.kill_and_restart()
                next_kill += a.kill_every
        self.sending = False
        sender.join()
        self.t_load_end = self.now()
        print("soak: load phase over at %.0f s: %d passes sent, %d kills" %
              (self.t_load_end, len(self.sent_order), len(self.kill_times)), file=sys.stderr)
        for _ in range(a.uploaders):
            self.upload_q.put(None)
        for t in threads[1:]:
            t.join(timeout=600)
            if t.is_alive():
                self.fail("upload_stuck", "an upload did not finish within 600 s")
        return self.finish()

    def frame_keys(self):
        per_job = self.args.frames // self.args.jobs
        return [(j, f) for j in range(self.args.jobs) for f in range(1, per_job + 1)]

    def finish(self):
        """Drains, then checks the final state against what was sent."""
        d = self.daemon
        self.check_alive()
        t_drain0 = self.now()
        expected = {k: len(v) for k, v in self.sent.items()}

        def drained():
            for (j, f), n in expected.items():
                fr = d.frames(self.jobs[j]).get(f)
                if not fr or fr["pending"] or fr["passes"] < n:
                    return False
            return True
        try:
            wait_until(drained, 900, 1.0, "every frame to count every pass")
        except AssertionError as e:
            self.fail("lost", str(e))
        self.drain_s = self.now() - t_drain0
        self.final = {}
        self.verify_frames()
        # Every client resumed and saw every frame's final version.
        finals = {(self.jobs[j], f): v["version"] for (j, f), v in self.final.items()}
        try:
            wait_until(lambda: all(c.caught_up(finals) for c in self.clients), 120, 0.5,
                       "every SSE client to see every frame's final version")
        except AssertionError:
            behind = [c.index for c in self.clients if not c.caught_up(finals)]
            self.fail("sse_missed_final", "%d client(s) never saw the final versions: %s"
                      % (len(behind), behind[:10]))
        self.sample_daemon(self.now())
        self.stopping = True
        rc = d.stop()
        if rc != 0:
            self.fail("crash", "SIGTERM at the end: exit %s" % rc)
        for c in self.clients:
            c.join(timeout=30)
        self.check_log()
        self.check_leftovers()
        self.missed = sorted(set().union(*[c.gap_versions for c in self.clients]))
        with open(self.daemon.log, "rb") as f:
            text = f.read().decode(errors="replace")
        for jid, f, v in self.missed:
            # An event lost with the killed process; a client resumes it from the history.
            if v not in self.history.get((jid, f), ()):
                self.fail("versions", "version %d of job %s frame %d: never announced and not in "
                          "the history (%s in the log)" % (
                              v, jid, f, "announced" if "job %s frame %d: version %d (" % (jid, f, v)
                              in text else "not announced"))
        for epoch, m in self.metrics_last.items():
            for k, v in m.items():
                if (k.startswith("proden_errors_total") or 'code="5xx"' in k or 'code="4xx"' in k) \
                        and v > 0:
                    self.fail("metrics", "epoch %d: %s = %g" % (epoch, k, v))
        for eid, data in sorted(self.error_events.items()):
            self.fail("error_event", json.dumps(data)[:400])
        for c in self.clients:
            for v in c.violations:
                self.fail("sse", "client %d: %s" % (c.index, v))
            if c.other_disconnects:
                self.fail("sse_disconnect", "client %d lost its stream %d time(s) without a kill"
                          % (c.index, c.other_disconnects))

    def verify_frames(self):
        d = self.daemon
        for key in sorted(self.sent):
            j, f = key
            jid = self.jobs[j]
            s, meta = d.frame(jid, f)
            if s != 200:
                self.fail("lost", "frame %s: GET -> %d" % (key, s))
                continue
            names = [p["pass"] for p in meta["pass_list"]]
            sent = self.sent[key]
            dup = len(names) - len(set(names))
            lost = sorted(set(sent) - set(names))
            extra = sorted(set(names) - set(sent))
            if dup or lost or extra or meta["passes"] != len(sent):
                self.fail("count", "job %s frame %d: %d sent, passes %d, %d listed, %d duplicate(s), "
                          "lost %s, unexpected %s" % (jid, f, len(sent), meta["passes"], len(names),
                                                      dup, lost[:10], extra[:10]))
            if meta["quarantined"]:
                self.fail("quarantined", "job %s frame %d: %s" % (jid, f, meta["quarantined"][:5]))
            s, hist = d.json("GET", "/api/v1/jobs/%s/frames/%d/history" % (jid, f))
            vs = [v["version"] for v in hist["versions"]] if s == 200 else []
            if any(b <= a for a, b in zip(vs, vs[1:])) or not vs or vs[-1] != meta["version"]:
                self.fail("versions", "job %s frame %d: history versions not strictly increasing "
                          "up to %d: ...%s" % (jid, f, meta["version"], vs[-5:]))
            self.final[key] = {"version": meta["version"], "passes": meta["passes"],
                               "history_points": len(vs)}
            self.history[(jid, f)] = set(vs)
        for jid in self.jobs:
            s, q = d.json("GET", "/api/v1/jobs/%s/quarantine" % jid)
            if s != 200 or q["quarantined"]:
                self.fail("quarantined", "job %s: %s %s" % (jid, s, str(q)[:300]))

    def check_log(self):
        with open(self.daemon.log, "rb") as f:
            text = f.read().decode(errors="replace")
        self.log_lines = text.count("\n")
        for line in text.split("\n"):
            m = re.search(r"proden\[\d+\] (warning|error|critical): ", line)
            if m:
                self.fail("log_" + m.group(1), line[:300])

    def check_leftovers(self):
        """No temp file left in the output directories, nothing stranded in the upload area."""
        d = self.daemon
        for j, jid in enumerate(self.jobs):
            out = os.path.join(d.allowed, "soak%d_out" % j)
            for n in os.listdir(out):
                if n.startswith("."):
                    self.fail("leftover", os.path.join(out, n))
            up = os.path.join(d.state, "jobs", jid, "uploads")
            for base, _, files in os.walk(up):
                for n in files:
                    self.fail("leftover", os.path.join(base, n))


class SseWatcher(threading.Thread):
    """One SSE client for the whole run: reconnects with Last-Event-ID whenever its stream ends,
    and checks every event as it arrives (constant memory: the last id, each frame's last
    version)."""

    def __init__(self, soak, index):
        super().__init__(daemon=True)
        self.soak = soak
        self.index = index
        self.last_id = None
        self.last_version = {}  # (job, frame) -> (version, kills_started when seen)
        self.connects = 0
        self.kill_reconnects = 0
        self.other_disconnects = 0
        self.events = 0
        self.frame_events = 0
        self.kill_gaps = 0  # versions never seen because a kill came between
        self.gap_versions = set()  # (job, frame, version) of those
        self.violations = []

    def caught_up(self, finals):
        return all(self.last_version.get(k, (0, 0))[0] >= v for k, v in finals.items())

    def violation(self, text):
        if len(self.violations) < 20:
            self.violations.append(text)

    def run(self):
        s = self.soak
        while not s.stopping:
            kills = s.kills_started
            try:
                c = SseClient(s.daemon, last_event_id=self.last_id, timeout=60)
            except CONNECTION_ERRORS:
                time.sleep(0.2)
                continue
            if " 200 " not in c.status_line + " ":
                s.fail("sse_status", "client %d: %s" % (self.index, c.status_line))
                c.close()
                time.sleep(1.0)
                continue
            self.connects += 1
            try:
                while True:
                    e = c.next_event()
                    c.all.clear()
                    self.handle(e, kills)
            except (CONNECTION_ERRORS + (ValueError,)) as ex:
                c.close()
                if s.stopping:
                    break
                if s.kills_started != kills:
                    self.kill_reconnects += 1
                else:
                    time.sleep(0.5)  # the kill may be starting; decide after a moment
                    if s.kills_started == kills:
                        self.other_disconnects += 1
                        s.fail("sse_disconnect_detail", "client %d: %r" % (self.index, ex))

    def handle(self, e, kills):
        self.events += 1
        eid = int(e["id"])
        if self.last_id is not None and eid <= int(self.last_id):
            self.violation("event id %d after %s" % (eid, self.last_id))
        self.last_id = str(eid)
        data = e.get("data") or {}
        if e["event"] == "frame":
            self.frame_events += 1
            key = (data["job"], data["frame"])
            v = data["version"]
            prev = self.last_version.get(key)
            if prev is not None:
                if v <= prev[0]:
                    self.violation("frame %s: version %d after %d" % (key, v, prev[0]))
                elif v > prev[0] + 1:
                    if prev[1] != kills:
                        self.kill_gaps += v - prev[0] - 1
                        self.gap_versions.update((key[0], key[1], m) for m in range(prev[0] + 1, v))
                    else:
                        self.violation("frame %s: version %d after %d on one connection"
                                       % (key, v, prev[0]))
            elif v != 1 and kills == 0:
                self.violation("frame %s: first version seen is %d" % (key, v))
            self.last_version[key] = (max(v, prev[0] if prev else 0), kills)
        elif e["event"] == "error":
            with self.soak.lock:
                self.soak.error_events[eid] = data


# ---------------------------------------------------------------------------------------------
# Analysis and report


def median(xs):
    return statistics.median(xs) if xs else None


def rss_analysis(soak):
    """Resident memory, like with like. Every epoch (one daemon process, `kill_every` long) is
    split in thirds: the first third is that process's warm-up (state loaded, caches filled),
    and its middle and last thirds are compared (growth within a process). Across epochs the
    last thirds are compared with the first epoch after the run's warm-up (`warmup` seconds, the
    first 3 minutes): growth from one process lifetime to the next as the state grows."""
    a = soak.args
    L = a.kill_every
    rows = []
    starts = soak.epoch_starts + [soak.t_load_end]
    for e in range(len(starts) - 1):
        s0 = max(starts[e], soak.t_load0)
        s1 = starts[e + 1]
        span = s1 - s0
        pts = [(t - s0, m) for (t, ep, m) in soak.rss if ep == e and s0 <= t < s1]
        mid = [m for (t, m) in pts if span / 3 <= t < 2 * span / 3]
        late = [m for (t, m) in pts if t >= 2 * span / 3]
        rows.append({"epoch": e, "start_s": s0 - soak.t_load0, "length_s": span,
                     "samples": len(pts), "mid_mib": median(mid), "late_mib": median(late),
                     "max_mib": max((m for _, m in pts), default=None),
                     "full": span >= 0.9 * L})
    for r in rows:
        r["within_growth"] = (r["late_mib"] / r["mid_mib"] - 1.0
                              if r["mid_mib"] and r["late_mib"] else None)
    checked = [r for r in rows if r["full"] and r["start_s"] >= a.warmup - 1.0]
    base = checked[0] if checked else None
    for r in rows:
        r["vs_baseline"] = (r["late_mib"] / base["late_mib"] - 1.0
                            if base and r["late_mib"] and base["late_mib"] else None)
    return rows, checked, base


def check_rss(soak, rows, checked, base):
    if not checked:
        soak.fail("rss", "no full epoch after the warm-up to measure")
        return
    for r in checked:
        if r["within_growth"] is None or r["within_growth"] >= GROWTH_LIMIT:
            soak.fail("rss", "epoch %d grew %s within its lifetime (middle third %s MiB -> last "
                      "third %s MiB)" % (r["epoch"], fmt_pct(r["within_growth"]), r["mid_mib"],
                                         r["late_mib"]))
        if r is not base and (r["vs_baseline"] is None or r["vs_baseline"] >= GROWTH_LIMIT):
            soak.fail("rss", "epoch %d's last third is %s above epoch %d's (%s vs %s MiB)"
                      % (r["epoch"], fmt_pct(r["vs_baseline"]), base["epoch"], r["late_mib"],
                         base["late_mib"]))


def fmt_pct(x):
    return "n/a" if x is None else "%+.1f %%" % (100.0 * x)


def fmt_mib(x):
    return "n/a" if x is None else "%.1f" % x


def plot(soak, path):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    fig, ax = plt.subplots(figsize=(9, 4))
    for e in range(len(soak.epoch_starts)):
        pts = [(t - soak.t_load0, m) for (t, ep, m) in soak.rss if ep == e]
        if pts:
            ax.plot([p[0] / 60 for p in pts], [p[1] for p in pts], color="C0", lw=1)
    for k in soak.kill_times:
        ax.axvline((k - soak.t_load0) / 60, color="C3", lw=0.8, ls="--")
    ax.set_xlabel("minutes (red: kill -9 and restart)")
    ax.set_ylabel("daemon RSS (MiB)")
    ax.set_ylim(bottom=0)
    if soak.backlog:
        ax2 = ax.twinx()
        ax2.plot([(t - soak.t_load0) / 60 for t, _ in soak.backlog], [b for _, b in soak.backlog],
                 color="C2", lw=0.8, alpha=0.7)
        ax2.set_ylabel("passes sent, not yet counted", color="C2")
        ax2.set_ylim(bottom=0)
    ax.set_title("proden serve soak: %d SSE clients, %g passes/s, kill -9 every %g s"
                 % (soak.args.clients, soak.args.rate, soak.args.kill_every))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def summary(soak, rows, base, command, png):
    a = soak.args
    clients = soak.clients
    per_client = [c.events for c in clients]
    frame_ev = [c.frame_events for c in clients]
    loads = [l for _, l in soak.loads]
    lat = sorted(soak.upload_lat)
    sent_by = {"watch": 0, "upload": 0}
    for v in soak.sent.values():
        for how in v.values():
            sent_by[how] += 1
    total_sent = sum(sent_by.values())
    counted = sum(v["passes"] for v in soak.final.values())
    versions = sum(v["version"] for v in soak.final.values())
    load_s = soak.t_load_end - soak.t_load0
    ok = not soak.errors
    L = ["## Soak (issue 11; `bench/soak.py`, `make soak`)", ""]
    L.append("Run %s on the 2-core VM (shared with other engineers' builds and renders), Release "
             "build, loopback, no token." % time.strftime("%Y-%m-%d"))
    L.append("")
    L.append("```")
    L.append(command)
    L.append("```")
    L.append("")
    L.append("| | |")
    L.append("|---|---|")
    L.append("| result | **%s** |" % ("PASS: 0 errors" if ok else "FAIL: %d violation(s)"
                                      % sum(soak.error_counts.values())))
    L.append("| load phase | %.1f min (+ %.1f s to drain after the last pass) |"
             % (load_s / 60, soak.drain_s))
    L.append("| load average (1 min), sampled every 5 s | min %.1f, mean %.1f, max %.1f |"
             % (min(loads), statistics.mean(loads), max(loads)) if loads else "| load | n/a |")
    L.append("| frames | %d (%d jobs x %d), %dx%d Cycles passes (12 channels, %d KiB), denoiser "
             "`%s`, mixer `auto` |" % (len(soak.sent), a.jobs, a.frames // a.jobs, a.size, a.size,
                                       a.size * a.size * 12 * 4 // 1024, a.denoiser))
    L.append("| passes sent | %d (%.2f/s): %d watched files, %d uploads (%d upload retries after "
             "kills) |" % (total_sent, total_sent / load_s, sent_by["watch"], sent_by["upload"],
                           soak.upload_retries))
    L.append("| passes counted | %d (every frame's `pass_list` = the passes sent: %s) |"
             % (counted, "yes" if counted == total_sent and not soak.error_counts.get("count")
                else "NO"))
    L.append("| versions published | %d (sum of the frames' final versions; %.1f/s) |"
             % (versions, versions / (load_s + soak.drain_s)))
    L.append("| kill -9 / restarts | %d, restart (SIGKILL -> listening) %s s |"
             % (len(soak.kill_times), ", ".join("%.1f" % r for r in soak.restart_s) or "-"))
    L.append("| SSE clients | %d; events received per client %d..%d (frame events %d..%d); "
             "reconnects after kills %d..%d; other disconnects %d |"
             % (len(clients), min(per_client), max(per_client), min(frame_ev), max(frame_ev),
                min(c.kill_reconnects for c in clients), max(c.kill_reconnects for c in clients),
                sum(c.other_disconnects for c in clients)))
    L.append("| versions not seen by a client (all across a kill; each in the frame's history) | "
             "%d in total over %d clients, %d distinct |"
             % (sum(c.kill_gaps for c in clients), len(clients), len(soak.missed)))
    if lat:
        L.append("| upload: sent -> acknowledged | p50 %.2f s, p99 %.2f s, max %.1f s |"
                 % (lat[len(lat) // 2], lat[int(len(lat) * 0.99)], lat[-1]))
    if soak.backlog:
        L.append("| backlog (sent - counted), sampled every 5 s | max %d, median %d |"
                 % (max(b for _, b in soak.backlog), median([b for _, b in soak.backlog])))
    L.append("| daemon queue depth (max sampled) | %d |" % soak.queue_depth_max)
    L.append("| daemon log | %d lines, warnings/errors: %d |" % (
        soak.log_lines, sum(v for k, v in soak.error_counts.items() if k.startswith("log_"))))
    L.append("")
    L.append("RSS of the daemon (VmRSS every 1 s). Each epoch is one daemon process (between "
             "kills); its first third is that process's warm-up; *within* compares its last third "
             "with its middle third (medians), *vs epoch %s* compares its last third with that "
             "of the first epoch after the run's %d s warm-up. Limit: growth < %d %%."
             % (base["epoch"] if base else "-", a.warmup, int(GROWTH_LIMIT * 100)))
    L.append("")
    L.append("| epoch | starts (min) | length (s) | middle third (MiB) | last third (MiB) | max "
             "(MiB) | within | vs epoch %s |" % (base["epoch"] if base else "-"))
    L.append("|---|---|---|---|---|---|---|---|")
    for r in rows:
        L.append("| %d | %.1f | %.0f | %s | %s | %s | %s | %s |" % (
            r["epoch"], r["start_s"] / 60, r["length_s"], fmt_mib(r["mid_mib"]),
            fmt_mib(r["late_mib"]), fmt_mib(r["max_mib"]),
            fmt_pct(r["within_growth"]) if r["start_s"] >= a.warmup - 1 else "(warm-up)",
            fmt_pct(r["vs_baseline"]) if r["start_s"] >= a.warmup - 1 else "(warm-up)"))
    L.append("")
    if png:
        L.append("![daemon RSS and backlog over the soak](results/%s)" % os.path.basename(png))
        L.append("")
    if ok:
        L.append("Errors: 0 (HTTP 5xx or unexpected 4xx, `error` events, daemon log warnings "
                 "or errors, crashes, SSE disconnects without a kill, duplicate or lost passes, "
                 "non-increasing versions or event ids).")
    else:
        L.append("Violations by kind: %s" % ", ".join("%s %d" % kv for kv in
                                                       sorted(soak.error_counts.items())))
        L.append("")
        L.append("```")
        L.extend(soak.errors[:40])
        L.append("```")
    return "\n".join(L) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=float(os.environ.get("SOAK_MINUTES", "30")))
    ap.add_argument("--kill-every", type=float, default=None,
                    help="seconds between kills (default 180, or half the run if shorter)")
    ap.add_argument("--warmup", type=float, default=None,
                    help="seconds of warm-up before RSS is judged (default: one kill interval)")
    ap.add_argument("--clients", type=int, default=200)
    ap.add_argument("--rate", type=float, default=20.0, help="passes per second, in total")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--size", type=int, default=64, help="frame width and height (<= 128)")
    ap.add_argument("--denoiser", default="nlmeans")
    ap.add_argument("--workers", type=int, default=0, help="worker_threads (0: the default)")
    ap.add_argument("--uploaders", type=int, default=4)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--binary", default=harness.BINARY)
    ap.add_argument("--samples", default=harness.SAMPLES)
    ap.add_argument("--report", help="write the markdown report here")
    ap.add_argument("--png", help="write the RSS plot here (needs python3-matplotlib)")
    ap.add_argument("--json", help="write the raw numbers here")
    args = ap.parse_args()
    if args.kill_every is None:
        args.kill_every = min(180.0, args.minutes * 60.0 / 2)
    if args.warmup is None:
        args.warmup = args.kill_every
    assert args.frames % args.jobs == 0
    harness.BINARY = args.binary
    command = " ".join(["bench/soak.py"] + sys.argv[1:])
    if "SOAK_MINUTES" in os.environ:
        command = "SOAK_MINUTES=%s %s" % (os.environ["SOAK_MINUTES"], command)
    niceness = os.getpriority(os.PRIO_PROCESS, 0)
    if niceness > 0:
        command = "nice -n %d %s" % (niceness, command)
    socket.setdefaulttimeout(None)
    with TempRoot("proden-soak-") as root:
        soak = Soak(args, root)
        try:
            soak.run()
        except Exception:  # noqa: BLE001 (reported as a violation, with what was measured)
            soak.fail("harness", traceback.format_exc())
        finally:
            soak.stopping = True
            soak.sending = False
            if soak.daemon and soak.daemon.proc:
                soak.daemon.stop()
        rows, checked, base = rss_analysis(soak)
        check_rss(soak, rows, checked, base)
        png = args.png if args.png and plot(soak, args.png) else None
        text = summary(soak, rows, base, command, png)
        print(text)
        if args.report:
            with open(args.report, "w") as f:
                f.write(text)
        if args.json:
            with open(args.json, "w") as f:
                json.dump({"rss": soak.rss, "kills": soak.kill_times, "epochs": soak.epoch_starts,
                           "loads": soak.loads, "backlog": soak.backlog, "rows": rows,
                           "final": {"%d/%d" % k: v for k, v in soak.final.items()},
                           "errors": soak.errors, "error_counts": soak.error_counts}, f, indent=1)
    if soak.errors:
        print("soak: FAILED, %d violation(s)" % sum(soak.error_counts.values()), file=sys.stderr)
        return 1
    print("soak: passed", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
