"""Test harness for `proden serve`: starts the real daemon on an ephemeral loopback port, talks
HTTP to it (standard library only), reads Server-Sent Events, and stops or kills it."""
import http.client
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import tempfile
import time
import unittest

BINARY = os.environ.get("PRODEN_BINARY", "build/proden")
SAMPLES = os.environ.get("PRODEN_SAMPLES_DIR", "samples")
CORNELL = [os.path.join(SAMPLES, "renders", "cornell", "pass_%02d.exr" % i) for i in range(8)]

FAST_WATCH = {"poll_interval_ms": 400, "settle_ms": 250, "tick_ms": 50, "max_attempts": 2}
# A ThreadSanitizer-built daemon (PRODEN_TSAN) runs the pipeline several times slower: waits for
# results stretch by this factor.
SLOWDOWN = 5.0 if os.environ.get("PRODEN_TSAN") else 1.0


def wait_until(pred, timeout=20.0, interval=0.05, what="condition"):
    """Polls pred() until it returns a truthy value (returned) or the timeout passes (raises)."""
    deadline = time.monotonic() + timeout * SLOWDOWN
    while True:
        v = pred()
        if v:
            return v
        if time.monotonic() > deadline:
            raise AssertionError("timed out waiting for " + what)
        time.sleep(interval)


class Daemon:
    """One `proden serve` process with its own state dir under `root`."""

    def __init__(self, root, state=None, token=None, config=None, extra=(), port=0):
        self.root = root
        self.state = state or os.path.join(root, "state")
        self.allowed = os.path.join(root, "allowed")
        os.makedirs(self.allowed, exist_ok=True)
        self.token = token
        self.config = dict(config or {})
        self.config.setdefault("watch", dict(FAST_WATCH))
        self.extra = list(extra)
        self.proc = None
        self.url = None
        self.port = None
        self.want_port = port  # 0 = ephemeral; a restart may reuse the last one (start(port=...))
        self.log = os.path.join(root, "daemon.log")

    def start(self, timeout=20.0, port=None):
        if port is not None:
            self.want_port = port
        cfg_path = os.path.join(self.root, "config.json")
        with open(cfg_path, "w") as f:
            json.dump(self.config, f)
        args = [BINARY, "serve", "--port", str(self.want_port), "--state-dir", self.state,
                "--allow-root", self.allowed, "--config", cfg_path] + self.extra
        if self.token:
            tf = os.path.join(self.root, "token")
            with open(tf, "w") as f:
                f.write(self.token + "\n")
            os.chmod(tf, 0o600)
            args += ["--token-file", tf]
        self.logf = open(self.log, "ab")
        self.log_start = self.logf.tell()
        self.proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=self.logf)
        deadline = time.monotonic() + timeout
        line = b""
        while time.monotonic() < deadline:
            line = self.proc.stdout.readline()
            if not line:
                break
            m = re.match(rb"listening on http://([0-9.]+):(\d+)", line)
            if m:
                self.host = m.group(1).decode()
                self.port = int(m.group(2))
                self.url = "http://%s:%d" % (self.host, self.port)
                return self
        self.proc.kill()
        raise AssertionError("daemon did not start: %r; log:\n%s" % (line, self.read_log()))

    def huge_pages(self, timeout=10.0):
        """How this run of the daemon pages its large blocks (advised, always, off, sanitizer), as
        its start-up log line says (docs/api.md, "Memory")."""
        line = re.compile(rb"listening on .*huge pages (\w+)\)")

        def logged():
            with open(self.log, "rb") as f:
                f.seek(self.log_start)
                m = line.search(f.read())
            return m.group(1).decode() if m else None
        return wait_until(logged, timeout, what="the start-up line's huge-page mode")

    def read_log(self):
        try:
            with open(self.log, "rb") as f:
                return f.read().decode(errors="replace")[-4000:]
        except OSError:
            return ""

    def stop(self, sig=signal.SIGTERM, timeout=30.0):
        if not self.proc:
            return None
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            rc = self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            rc = self.proc.wait()
            raise AssertionError("daemon did not stop on %s; log:\n%s" % (sig, self.read_log()))
        finally:
            self.proc.stdout.close()
            self.logf.close()
        self.proc = None
        self.check_sanitizer_reports()
        return rc

    def check_sanitizer_reports(self):
        """Fails when this run of the daemon printed a ThreadSanitizer (or ASan/UBSan) report."""
        with open(self.log, "rb") as f:
            f.seek(self.log_start)
            text = f.read().decode(errors="replace")
        for marker in ("WARNING: ThreadSanitizer", "ERROR: AddressSanitizer", "runtime error:"):
            i = text.find(marker)
            if i >= 0:
                raise AssertionError("daemon sanitizer report:\n" + text[max(0, i - 200):i + 6000])

    def kill9(self):
        return self.stop(signal.SIGKILL)

    # ---- HTTP ----
    def request(self, method, path, body=None, headers=None, auth=True, timeout=30.0):
        """Returns (status, headers dict (lower-case keys), body bytes)."""
        h = dict(headers or {})
        if auth and self.token and "Authorization" not in h:
            h["Authorization"] = "Bearer " + self.token
        if isinstance(body, (dict, list)):
            body = json.dumps(body).encode()
            h.setdefault("Content-Type", "application/json")
        conn = http.client.HTTPConnection(self.host, self.port, timeout=timeout)
        try:
            conn.request(method, path, body=body, headers=h)
            r = conn.getresponse()
            data = r.read()
            return r.status, {k.lower(): v for k, v in r.getheaders()}, data
        finally:
            conn.close()

    def json(self, method, path, body=None, **kw):
        status, headers, data = self.request(method, path, body, **kw)
        try:
            parsed = json.loads(data) if data else None
        except ValueError:
            parsed = {"raw": data.decode(errors="replace")}
        return status, parsed

    def create_job(self, name, watch_dir=None, out_dir=None, pattern="pass_{pass}/beauty_{frame}.exr",
                   **extra):
        body = {"name": name, "output": {"dir": out_dir or os.path.join(self.allowed, name + "_out")}}
        if watch_dir is not None:
            body["watch"] = {"dir": watch_dir, "pattern": pattern}
        body.update(extra)
        status, j = self.json("POST", "/api/v1/jobs", body)
        assert status == 201, (status, j)
        return j["id"]

    def frames(self, job):
        status, j = self.json("GET", "/api/v1/jobs/%s/frames" % job)
        assert status == 200, (status, j)
        return {f["frame"]: f for f in j["frames"]}

    def frame(self, job, frame):
        return self.json("GET", "/api/v1/jobs/%s/frames/%d" % (job, frame))

    def wait_passes(self, job, frame, passes, timeout=30.0):
        def ok():
            f = self.frames(job).get(frame)
            return f if f and f["passes"] >= passes and not f["pending"] else None
        return wait_until(ok, timeout, what="frame %d to reach %d passes" % (frame, passes))


def metric(d, name):
    """The first sample in d's /metrics of `name` (a metric, or a metric with its labels), else 0."""
    s, h, body = d.request("GET", "/metrics")
    for line in body.decode().split("\n"):
        if line.startswith(name + " ") or line.startswith(name + "{"):
            return float(line.rsplit(" ", 1)[1])
    return 0.0


class SseClient:
    """A raw-socket Server-Sent Events reader."""

    def __init__(self, daemon, last_event_id=None, timeout=10.0):
        self.sock = socket.create_connection((daemon.host, daemon.port), timeout=timeout)
        req = "GET /api/v1/events HTTP/1.1\r\nHost: x\r\nAccept: text/event-stream\r\n"
        if last_event_id is not None:
            req += "Last-Event-ID: %s\r\n" % last_event_id
        self.sock.sendall((req + "\r\n").encode())
        self.buf = b""
        head = self._read_until(b"\r\n\r\n")
        self.status_line = head.split(b"\r\n", 1)[0].decode()
        self.headers = head.decode(errors="replace").lower()
        self.comments = 0
        self.all = []  # every event read, in order

    def _read_until(self, sep):
        while sep not in self.buf:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise EOFError("stream closed")
            self.buf += chunk
        out, self.buf = self.buf.split(sep, 1)
        return out

    def next_event(self):
        """Returns dict(id, event, data) for the next event, skipping comments/retry lines."""
        while True:
            block = self._read_until(b"\n\n").decode()
            ev = {}
            for line in block.split("\n"):
                if line.startswith(":"):
                    self.comments += 1
                    continue
                k, _, v = line.partition(": ")
                if k == "data":
                    ev["data"] = json.loads(v)
                elif k in ("id", "event"):
                    ev[k] = v
            if "event" in ev:
                self.all.append(ev)
                return ev

    def events_until(self, pred, timeout=20.0):
        """Reads events until pred(event) holds; returns all events read."""
        self.sock.settimeout(timeout)
        out = []
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            e = self.next_event()
            out.append(e)
            if pred(e):
                return out
        raise AssertionError("event not seen; got %r" % out)

    def close(self):
        self.sock.close()


class TempRoot:
    def __init__(self, prefix="proden-svc-"):
        self.path = tempfile.mkdtemp(prefix=prefix)

    def __enter__(self):
        return self.path

    def __exit__(self, *a):
        shutil.rmtree(self.path, ignore_errors=True)


def place_atomic(src, dst):
    """Copies src to dst the way a well-behaved renderer does: temp name, then rename."""
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    tmp = os.path.join(os.path.dirname(dst), "." + os.path.basename(dst) + ".tmp")
    shutil.copyfile(src, tmp)
    os.rename(tmp, dst)


class SharedDaemonTest(unittest.TestCase):
    """One daemon (DAEMON_CONFIG, if set) on a temporary root for all the tests of a class; it
    must stop cleanly when they are done."""
    DAEMON_CONFIG = None

    @classmethod
    def setUpClass(cls):
        cls.tmp = TempRoot()
        cls.root = cls.tmp.__enter__()
        cls.d = Daemon(cls.root, config=cls.DAEMON_CONFIG).start()

    @classmethod
    def tearDownClass(cls):
        rc = cls.d.stop()
        cls.tmp.__exit__(None, None, None)
        assert rc == 0, rc
