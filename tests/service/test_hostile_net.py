"""Hostile clients against the real daemon (issue 11): request bytes that are not UTF-8, uploads
large enough to stall or exhaust it, and event streams opened until no connection is left. The
daemon must answer 400 naming the part, keep /livez answering within a generous deadline, hold
no upload body in memory, stop on SIGTERM in bounded time, and keep connections for health checks
and authenticated requests."""
import json
import os
import socket
import sys
import threading
import time
import unittest

sys.path.insert(0, os.path.dirname(__file__))
from harness import SLOWDOWN, Daemon, TempRoot  # noqa: E402
import hostile_support as hf  # noqa: E402
from hostile_support import LIVEZ_DEADLINE, vm_hwm_mib  # noqa: E402

TOKEN = "hostile-net-token-0123456789"


def raw_request(d, data, source=None, timeout=10.0):
    """Sends raw bytes; returns (status, body bytes) of the response (the daemon closes)."""
    s = socket.create_connection((d.host, d.port), timeout=timeout,
                                 source_address=(source, 0) if source else None)
    try:
        s.sendall(data)
        buf = b""
        while b"\r\n\r\n" not in buf:
            chunk = s.recv(65536)
            if not chunk:
                break
            buf += chunk
        head, _, body = buf.partition(b"\r\n\r\n")
        length = 0
        for line in head.split(b"\r\n")[1:]:
            k, _, v = line.partition(b":")
            if k.strip().lower() == b"content-length":
                length = int(v)
        while len(body) < length:
            chunk = s.recv(65536)
            if not chunk:
                break
            body += chunk
        status = int(head.split(b" ")[1]) if head.startswith(b"HTTP/1.1 ") else 0
        return status, body
    finally:
        s.close()


def get(path, extra=b""):
    return b"GET " + path + b" HTTP/1.1\r\nHost: x\r\nConnection: close\r\n" + extra + b"\r\n"


class Stream:
    """An event-stream request; status 200 keeps it open."""

    def __init__(self, d, source=None):
        self.sock = socket.create_connection((d.host, d.port), timeout=10,
                                             source_address=(source, 0) if source else None)
        self.sock.sendall(b"GET /api/v1/events HTTP/1.1\r\nHost: x\r\n\r\n")
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = self.sock.recv(4096)
            if not chunk:
                break
            head += chunk
        self.status = int(head.split(b" ")[1]) if head.startswith(b"HTTP/1.1 ") else 0

    def close(self):
        self.sock.close()


class LivezProbe(threading.Thread):
    """Polls /livez until stopped; records the slowest answer (a failure counts as infinite)."""

    def __init__(self, d):
        super().__init__(daemon=True)
        self.d = d
        self.worst = 0.0
        self.count = 0
        self.halt = threading.Event()

    def run(self):
        while not self.halt.is_set():
            t0 = time.monotonic()
            try:
                s, _, _ = self.d.request("GET", "/livez", timeout=30)
                dt = time.monotonic() - t0 if s == 200 else float("inf")
            except OSError:
                dt = float("inf")
            self.worst = max(self.worst, dt)
            self.count += 1
            time.sleep(0.02)

    def stop(self):
        self.halt.set()
        self.join()


def valid_exr(width, height):
    return hf.exr(width=width, height=height, value=0.5)


class RequestBytesTest(unittest.TestCase):
    """Class 1 over HTTP: bytes that are not UTF-8 in a URL, a header or a body are a 400 naming
    the part, never a 500."""

    def test_non_utf8_request_bytes(self):
        with TempRoot() as root:
            d = Daemon(root).start()
            try:
                jid = d.create_job("bytes")
                cases = [
                    (get(b"/api/v1/jobs/\xff\xfe"), "path segment 4"),
                    (get(b"/api/v1/jobs/%FF%FE"), "path segment 4"),
                    (get(b"/api/v1/jobs/a%00b"), "path segment 4"),
                    (get(b"/api/v1/jobs/%C0%AF/frames"), "path segment 4"),
                    (get(b"/api/v1/jobs/" + jid.encode() + b"/frames/1/image?format=%ff"),
                     "query parameter 'format'"),
                    (get(b"/api/v1/jobs?la%ffyer=1"), "query parameter name"),
                    (get(b"/api/v1/events?last_event_id=%ff"), "query parameter"),
                    (get(b"/api/v1/events", b"Last-Event-ID: \xff\xfe\r\n"), "Last-Event-ID"),
                ]
                for body in (b'{"name": "\xff", "output": {"dir": "/x"}}',
                             b'{"name": "ok", "output": {"dir": "/\xc3\x28"}}'):
                    cases.append((b"POST /api/v1/jobs HTTP/1.1\r\nHost: x\r\nConnection: close\r\n"
                                  b"Content-Type: application/json\r\nContent-Length: %d\r\n\r\n"
                                  % len(body) + body, "not UTF-8"))
                for req, part in cases:
                    status, body = raw_request(d, req)
                    self.assertEqual(status, 400, (req, body))
                    err = json.loads(body.decode("utf-8"))["error"]
                    self.assertIn(part, err["message"], req)
                # Valid UTF-8 that names nothing is an ordinary 4xx.
                status, body = raw_request(d, get(b"/api/v1/jobs/%C3%A9"))
                self.assertEqual(status, 404, body)
                status, body = raw_request(
                    d, b"PUT /api/v1/jobs/" + jid.encode() + b"/frames/1/passes/%C3%A9 HTTP/1.1\r\n"
                       b"Host: x\r\nContent-Length: 4\r\nConnection: close\r\n\r\nabcd")
                self.assertEqual(status, 400, body)
                s, _, _ = d.request("GET", "/livez")
                self.assertEqual(s, 200)
                s, _, metrics = d.request("GET", "/metrics")
                self.assertNotIn(b'proden_http_requests_total{code="5xx"}', metrics)
            finally:
                self.assertEqual(d.stop(), 0)


class UploadTest(unittest.TestCase):
    """Class 5: uploads are streamed to disk and validated off the I/O threads."""

    def test_uploads_and_renditions_do_not_stall_livez(self):
        """Validating large uploads and decoding/encoding renditions of a large frame run off the
        I/O threads: /livez keeps answering meanwhile."""
        with TempRoot() as root:
            d = Daemon(root).start()
            try:
                jid = d.create_job("big", pipeline={"denoiser": "none"})
                # 48 MiB of float RGB; 3 MiB under ThreadSanitizer, whose daemon still spends
                # longer on those (~20 s, 100 s at 12 MiB) than the Release one on 48 MiB, so a
                # stall of the I/O threads stays as visible.
                side = 512 if SLOWDOWN > 1 else 2048
                body = valid_exr(side, side)
                self.assertGreater(len(body), side * side * 12)
                t0 = time.monotonic()
                probe = LivezProbe(d)
                probe.start()
                results = {}

                def up(name):
                    results[name] = d.json("PUT", "/api/v1/jobs/%s/frames/1/passes/%s" % (jid, name),
                                           body, timeout=180)
                threads = [threading.Thread(target=up, args=(n,)) for n in ("a", "b")]
                for t in threads:
                    t.start()
                for t in threads:
                    t.join()
                d.wait_passes(jid, 1, 2, timeout=180)
                print("uploads+frame: %.1f s" % (time.monotonic() - t0), file=sys.stderr)

                def rendition(layer, fmt):
                    results[layer + fmt] = d.request(
                        "GET", "/api/v1/jobs/%s/frames/1/image?format=%s&layer=%s" % (jid, fmt, layer),
                        timeout=180)[0]
                threads = [threading.Thread(target=rendition, args=a) for a in
                           (("render", "png"), ("variance", "png"), ("result", "png"),
                            ("render", "exr"))]
                for t in threads:
                    t.start()
                for t in threads:
                    t.join()
                probe.stop()
                print("total: %.1f s, worst livez %.2f s" % (time.monotonic() - t0, probe.worst),
                      file=sys.stderr)
                for name in ("a", "b"):
                    self.assertEqual(results[name][0], 202, results[name])
                for k in ("renderpng", "variancepng", "resultpng", "renderexr"):
                    self.assertEqual(results[k], 200, k)
                self.assertGreater(probe.count, 5)
                self.assertLess(probe.worst, LIVEZ_DEADLINE, "/livez stalled by uploads/renditions")
            finally:
                self.assertEqual(d.stop(timeout=60), 0)

    def test_large_uploads_are_not_held_in_memory(self):
        with TempRoot() as root:
            d = Daemon(root, config={"limits": {"max_upload_bytes": 512 << 20}}).start()
            try:
                jid = d.create_job("huge")
                size = 400 << 20
                base = vm_hwm_mib(d)
                results = {}

                def up(name):
                    s = socket.create_connection((d.host, d.port), timeout=120)
                    try:
                        s.sendall(b"PUT /api/v1/jobs/%s/frames/1/passes/%s HTTP/1.1\r\nHost: x\r\n"
                                  b"Content-Length: %d\r\nConnection: close\r\n\r\n"
                                  % (jid.encode(), name.encode(), size))
                        chunk = b"\x76\x2f\x31\x01" + b"\0" * ((1 << 20) - 4)
                        s.sendall(chunk)
                        zeros = b"\0" * (1 << 20)
                        for _ in range(size // len(zeros) - 1):
                            s.sendall(zeros)
                        results[name] = s.recv(4096)
                    finally:
                        s.close()
                t0 = time.monotonic()
                threads = [threading.Thread(target=up, args=(n,)) for n in ("a", "b")]
                for t in threads:
                    t.start()
                for t in threads:
                    t.join(150)
                self.assertLess(time.monotonic() - t0, 120, "no answer to large uploads")
                for name in ("a", "b"):
                    self.assertTrue(results.get(name, b"").startswith(b"HTTP/1.1 400"), results)
                grew = vm_hwm_mib(d) - base
                print("2 x %d MiB uploads: answered in %.1f s, peak RSS grew %.0f MiB"
                      % (size >> 20, time.monotonic() - t0, grew), file=sys.stderr)
                self.assertLess(grew, 200, "upload bodies were held in memory")
                # Nothing is left of them on disk either.
                left = []
                for dirpath, _, files in os.walk(os.path.join(d.state, "jobs", jid)):
                    left += [os.path.join(dirpath, f) for f in files if f != "job.json"]
                self.assertEqual(left, [])
            finally:
                self.assertEqual(d.stop(timeout=60), 0)

    def test_sigterm_with_uploads_in_flight(self):
        with TempRoot() as root:
            d = Daemon(root).start()
            jid = d.create_job("term", pipeline={"denoiser": "none"})
            socks = []
            for name in ("a", "b"):
                s = socket.create_connection((d.host, d.port), timeout=30)
                s.sendall(b"PUT /api/v1/jobs/%s/frames/1/passes/%s HTTP/1.1\r\nHost: x\r\n"
                          b"Content-Length: %d\r\n\r\n" % (jid.encode(), name.encode(), 300 << 20))
                s.sendall(b"\x76\x2f\x31\x01" + b"\0" * (20 << 20))  # then stalls
                socks.append(s)
            time.sleep(0.5)
            t0 = time.monotonic()
            rc = d.stop(timeout=30)
            self.assertEqual(rc, 0)
            self.assertLess(time.monotonic() - t0, 20, "SIGTERM did not finish")
            for s in socks:
                s.close()
            spooled = [f for _, _, files in os.walk(os.path.join(d.state, "jobs", jid, "uploads"))
                       for f in files]
            self.assertEqual(spooled, [])


class ConnectionLimitTest(unittest.TestCase):
    """Class 7: event streams have their own limit and a per-client cap; the last connections
    are kept for health checks and authenticated requests."""

    LIMITS = {"max_connections": 64, "reserved_connections": 8, "max_sse_streams": 24,
              "max_sse_per_client": 8, "request_timeout_ms": 20000, "idle_timeout_ms": 20000}

    def test_streams_cannot_take_every_connection(self):
        with TempRoot() as root:
            # Reads open to anyone (the operator's choice): the worst case, streams need no token.
            d = Daemon(root, token=TOKEN,
                       config={"limits": self.LIMITS, "open_reads": True}).start()
            streams, idle = [], []
            try:
                # One client: its share, then 429.
                mine = [Stream(d) for _ in range(12)]
                streams += mine
                self.assertEqual([s.status for s in mine], [200] * 8 + [429] * 4)
                # Many clients (loopback addresses): the stream limit, then 503.
                for i in range(2, 10):
                    for _ in range(8):
                        streams.append(Stream(d, source="127.0.0.%d" % i))
                ok = [s for s in streams if s.status == 200]
                self.assertEqual(len(ok), 24)
                self.assertTrue(all(s.status in (429, 503) for s in streams if s.status != 200))
                for s in streams:
                    if s.status != 200:
                        s.close()
                # Everyone else is still served.
                self.assertEqual(d.json("GET", "/livez")[0], 200)
                self.assertEqual(d.json("GET", "/api/v1/jobs", auth=False)[0], 200)
                # Now fill every ordinary connection with idle sockets: 24 streams + 32 idle.
                for _ in range(64 - 8 - 24):
                    idle.append(socket.create_connection((d.host, d.port), timeout=10))
                time.sleep(0.3)
                # The reserve: health checks and authenticated requests only.
                for _ in range(3):
                    self.assertEqual(d.json("GET", "/livez", auth=False)[0], 200)
                s, b = d.json("POST", "/api/v1/jobs",
                              {"name": "reserved", "output": {"dir": os.path.join(d.allowed, "r")}})
                self.assertEqual(s, 201, b)
                s, b = d.json("GET", "/api/v1/jobs", auth=False)
                self.assertEqual(s, 503, b)
                late = Stream(d, source="127.0.0.20")
                late.close()
                self.assertEqual(late.status, 503)
            finally:
                for s in streams:
                    s.close()
                for s in idle:
                    s.close()
                self.assertEqual(d.stop(), 0)


if __name__ == "__main__":
    unittest.main(verbosity=2)
