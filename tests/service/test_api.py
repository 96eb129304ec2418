"""`proden serve` API tests against the real binary: job lifecycle, errors, limits, auth, path
safety, uploads, metrics format, probes."""
import os
import re
import socket
import struct
import subprocess
import sys
import unittest

sys.path.insert(0, os.path.dirname(__file__))
from harness import SharedDaemonTest, BINARY, CORNELL, Daemon, TempRoot, wait_until  # noqa: E402

TOKEN = "s3cret-token-0123456789abcdef"
LIMITS = {"max_body_bytes": 4096, "max_upload_bytes": 400000, "max_header_bytes": 4096,
          "request_timeout_ms": 2000, "idle_timeout_ms": 2000}


class ApiTest(SharedDaemonTest):
    DAEMON_CONFIG = {"limits": LIMITS}

    def assert_error(self, status, body, want_status, want_code=None):
        self.assertEqual(status, want_status, body)
        self.assertIn("error", body)
        self.assertIn("code", body["error"])
        self.assertIn("message", body["error"])
        if want_code:
            self.assertEqual(body["error"]["code"], want_code)

    def test_probes(self):
        self.assertEqual(self.d.json("GET", "/livez")[0], 200)
        self.assertEqual(self.d.json("GET", "/readyz")[0], 200)

    def test_job_lifecycle(self):
        watch = os.path.join(self.d.allowed, "life_watch")
        status, job = self.d.json("POST", "/api/v1/jobs", {
            "name": "life", "watch": {"dir": watch, "pattern": "pass_{pass}/beauty_####.exr"},
            "renderer": "cycles", "pipeline": {"denoiser": "auto", "mixer": "auto"},
            "output": {"dir": os.path.join(self.d.allowed, "life_out"), "formats": ["exr", "png"]}})
        self.assertEqual(status, 201, job)
        jid = job["id"]
        self.assertEqual(job["name"], "life")
        self.assertEqual(job["output"]["formats"], ["exr", "png"])
        self.assertTrue(os.path.isdir(watch))
        status, lst = self.d.json("GET", "/api/v1/jobs")
        self.assertIn(jid, [j["id"] for j in lst["jobs"]])
        self.assertEqual(self.d.json("GET", "/api/v1/jobs/" + jid)[1]["name"], "life")
        # Same name twice: conflict.
        status, body = self.d.json("POST", "/api/v1/jobs", {"name": "life", "output": {"dir": watch}})
        self.assert_error(status, body, 409, "conflict")
        # Pause, resume.
        status, j = self.d.json("POST", "/api/v1/jobs/%s/pause" % jid)
        self.assertEqual((status, j["state"]), (200, "paused"))
        status, j = self.d.json("POST", "/api/v1/jobs/%s/resume" % jid)
        self.assertEqual((status, j["state"]), (200, "active"))
        # Frames of an empty job; unknown frame.
        self.assertEqual(self.d.frames(jid), {})
        self.assert_error(*self.d.frame(jid, 7), 404, "not_found")
        # Delete.
        status, _, _ = self.d.request("DELETE", "/api/v1/jobs/" + jid)
        self.assertEqual(status, 204)
        self.assert_error(*self.d.json("GET", "/api/v1/jobs/" + jid), 404, "not_found")
        self.assert_error(*self.d.json("DELETE", "/api/v1/jobs/" + jid), 404, "not_found")

    def test_malformed_requests(self):
        s, b = self.d.json("POST", "/api/v1/jobs", b"{not json", headers={"Content-Type": "application/json"})
        self.assert_error(s, b, 400, "invalid_json")
        s, b = self.d.json("POST", "/api/v1/jobs", {"name": "x"})
        self.assert_error(s, b, 400, "invalid_field")
        s, b = self.d.json("POST", "/api/v1/jobs", {"name": "bad/name", "output": {"dir": self.d.allowed}})
        self.assert_error(s, b, 400, "invalid_field")
        s, b = self.d.json("POST", "/api/v1/jobs", {"name": "nopass", "output": {"dir": self.d.allowed},
                                                   "watch": {"dir": self.d.allowed, "pattern": "f_{frame}.exr"}})
        self.assert_error(s, b, 400, "invalid_field")
        s, b = self.d.json("POST", "/api/v1/jobs", {"name": "m", "output": {"dir": self.d.allowed},
                                                   "pipeline": {"denoiser": "magic"}})
        self.assert_error(s, b, 400, "invalid_field")
        s, b = self.d.json("POST", "/api/v1/jobs", [1, 2])
        self.assert_error(s, b, 400)
        self.assert_error(*self.d.json("GET", "/api/v1/nothing"), 404, "not_found")
        self.assert_error(*self.d.json("PATCH", "/api/v1/jobs"), 405, "method_not_allowed")
        self.assert_error(*self.d.json("GET", "/api/v1/jobs/x/frames/abc"), 400)
        # Not HTTP at all.
        with socket.create_connection((self.d.host, self.d.port), timeout=5) as s:
            s.sendall(b"HELLO\x00\x01 garbage\r\n\r\n")
            data = s.recv(4096)
            self.assertTrue(data.startswith(b"HTTP/1.1 400"), data)

    def test_limits(self):
        big = {"name": "big", "output": {"dir": self.d.allowed}, "pad": "x" * 10000}
        s, b = self.d.json("POST", "/api/v1/jobs", big)
        self.assert_error(s, b, 413, "payload_too_large")
        s, b = self.d.json("GET", "/livez", headers={"X-Big": "y" * 8000})
        self.assertEqual(s, 431)
        # A client that sends half a request and stalls is cut off by the time limit.
        with socket.create_connection((self.d.host, self.d.port), timeout=10) as s:
            s.sendall(b"POST /api/v1/jobs HTTP/1.1\r\nHost: x\r\nContent-Length: 100\r\n\r\n{")
            s.settimeout(10)
            t0 = __import__("time").monotonic()
            data = s.recv(4096)
            self.assertLess(__import__("time").monotonic() - t0, 8)
            self.assertEqual(data, b"")  # closed without a response

    def test_path_escapes(self):
        outside = os.path.join(self.root, "outside")
        os.makedirs(outside, exist_ok=True)
        cases = [
            (os.path.join(self.d.allowed, "..", "outside"), 400),  # '..' refused outright
            (outside, 403),
            ("relative/dir", 400),
            ("/etc", 403),
        ]
        link = os.path.join(self.d.allowed, "escape_link")
        if not os.path.lexists(link):
            os.symlink(outside, link)
        cases.append((link, 403))
        cases.append((os.path.join(link, "sub"), 403))
        for i, (path, want) in enumerate(cases):
            for field in ("output", "watch"):
                body = {"name": "esc%d%s" % (i, field), "output": {"dir": os.path.join(self.d.allowed, "o")}}
                if field == "output":
                    body["output"]["dir"] = path
                else:
                    body["watch"] = {"dir": path, "pattern": "p{pass}_{frame}.exr"}
                s, b = self.d.json("POST", "/api/v1/jobs", body)
                self.assertEqual(s, want, (path, field, b))
                self.assertIn(b["error"]["code"], ("invalid_path", "path_forbidden", "invalid_field"))
        self.assertFalse(os.path.exists(os.path.join(outside, "sub")))

    def test_upload(self):
        jid = self.d.create_job("up")
        path = "/api/v1/jobs/%s/frames/12/passes/%s"
        with open(CORNELL[0], "rb") as f:
            p0 = f.read()
        with open(CORNELL[1], "rb") as f:
            p1 = f.read()
        s, b = self.d.json("PUT", path % (jid, "a"), p0)
        self.assertEqual(s, 202, b)
        self.assertEqual(b["status"], "queued")
        s, b = self.d.json("PUT", path % (jid, "a"), p0)  # the same bytes again: idempotent
        self.assertIn((s, b["status"]), ((202, "queued"), (200, "ingested")), b)
        s, b = self.d.json("PUT", path % (jid, "a"), p1)  # other bytes for the same pass
        self.assert_error(s, b, 409, "conflict")
        s, b = self.d.json("PUT", path % (jid, "b"), b"not an exr at all")
        self.assert_error(s, b, 400, "invalid_pass")
        s, b = self.d.json("PUT", path % (jid, "c"), b"\0" * 500000)
        self.assert_error(s, b, 413, "payload_too_large")
        s, b = self.d.json("PUT", path % (jid, "bad.name"), p1)
        self.assert_error(s, b, 400, "invalid_pass")
        s, b = self.d.json("PUT", path % ("nojob", "a"), p1)
        self.assert_error(s, b, 404, "not_found")
        s, b = self.d.json("PUT", path % (jid, "b"), p1)
        self.assertEqual(s, 202, b)
        f = self.d.wait_passes(jid, 12, 2)
        self.assertEqual(f["spp"], 8.0)
        self.assertEqual(f["estimated_error"]["source"], "variance+cross-validation")
        self.assertGreater(f["estimated_mse"], 0)
        s, meta = self.d.frame(jid, 12)
        self.assertEqual((meta["width"], meta["height"]), (128, 128))
        self.assertEqual([p["pass"] for p in meta["pass_list"]], ["a", "b"])
        s, h, exr = self.d.request("GET", "/api/v1/jobs/%s/frames/12/image?format=exr" % jid)
        self.assertEqual(s, 200)
        self.assertEqual(exr[:4], b"\x76\x2f\x31\x01")  # OpenEXR magic
        for layer in ("result", "render", "variance"):
            s, h, png = self.d.request("GET", "/api/v1/jobs/%s/frames/12/image?format=png&layer=%s" % (jid, layer))
            self.assertEqual((s, h["content-type"]), (200, "image/png"))
            self.assertEqual(png[:8], b"\x89PNG\r\n\x1a\n")
        for layer in ("denoised", "alpha", "sure"):
            s, h, png = self.d.request("GET", "/api/v1/jobs/%s/frames/12/image?format=png&layer=%s" % (jid, layer))
            self.assertEqual(s, 200, layer)
        s, h, exr = self.d.request("GET", "/api/v1/jobs/%s/frames/12/image?format=exr&layer=denoised" % jid)
        self.assertEqual((s, exr[:4]), (200, b"\x76\x2f\x31\x01"))
        s, b = self.d.json("GET", "/api/v1/jobs/%s/frames/12/image?format=png&layer=bogus" % jid)
        self.assert_error(s, b, 400)
        s, b = self.d.json("GET", "/api/v1/jobs/%s/frames/12/image?format=tiff" % jid)
        self.assert_error(s, b, 400)
        # The dashboard's additions: colour-mapped layers, thumbnails, revalidation, history.
        base = "/api/v1/jobs/%s/frames/12/image?format=png" % jid
        s, h, _ = self.d.request("GET", base + "&layer=sure")
        self.assertEqual((s, h["x-proden-colormap"], h["x-proden-scale"]), (200, "magma", "log"))
        lo, hi = map(float, h["x-proden-range"].split())
        self.assertTrue(0 < lo < hi, h["x-proden-range"])
        s, h, thumb = self.d.request("GET", base + "&layer=result&size=32")
        self.assertEqual(s, 200)
        self.assertEqual(struct.unpack(">II", thumb[16:24]), (32, 32))  # PNG IHDR width, height
        s, _, _ = self.d.request("GET", base + "&layer=result&size=32", headers={"If-None-Match": h["etag"]})
        self.assertEqual(s, 304)
        self.assert_error(*self.d.json("GET", base + "&size=3"), 400, "invalid_parameter")
        s, hist = self.d.json("GET", "/api/v1/jobs/%s/frames/12/history" % jid)
        self.assertEqual(s, 200)
        passes = [v["passes"] for v in hist["versions"]]  # the two uploads may share a version
        self.assertEqual((passes, passes[-1]), (sorted(passes), 2))
        last = hist["versions"][-1]
        self.assertEqual((last["version"], last["spp"]), (f["version"], 8.0))
        self.assertGreater(last["render_mse"], 0)
        s, jh = self.d.json("GET", "/api/v1/jobs/%s/history" % jid)
        self.assertEqual([x["frame"] for x in jh["frames"]], [12])
        self.assert_error(*self.d.json("GET", "/api/v1/jobs/%s/frames/99/history" % jid), 404)
        s, q = self.d.json("GET", "/api/v1/jobs/%s/quarantine" % jid)
        self.assertEqual((s, q["quarantined"]), (200, []))
        s, maps = self.d.json("GET", "/api/v1/colormaps")
        self.assertEqual(maps["layers"]["alpha"], {"kind": "scalar", "colormap": "viridis", "scale": "linear"})
        # Every layer the pipeline can write is described, cvspread (a linear denoiser's) too.
        self.assertEqual(maps["layers"]["cvspread"], {"kind": "scalar", "colormap": "magma", "scale": "log"})
        self.assertIn("error", maps["layers"])
        self.assertEqual(len(maps["colormaps"]["magma"]), 32)
        # A stored upload is removed once accumulated.
        ups = os.path.join(self.d.state, "jobs", jid, "uploads", "12")
        wait_until(lambda: not [n for n in os.listdir(ups) if not n.startswith(".")], 10, what="uploads cleaned")

    def test_network_mixer_job(self):
        # The same two passes through a closed-form job and a learned-mixer job: both publish,
        # and the published results differ (the network's alpha is really used).
        results = {}
        for mixer in ("closed-form", "network"):
            jid = self.d.create_job("mix_" + mixer.replace("-", "_"), pipeline={"mixer": mixer})
            for name, path in (("a", CORNELL[0]), ("b", CORNELL[1])):
                with open(path, "rb") as f:
                    s, b = self.d.json("PUT", "/api/v1/jobs/%s/frames/3/passes/%s" % (jid, name), f.read())
                self.assertEqual(s, 202, b)
            f = self.d.wait_passes(jid, 3, 2)
            self.assertGreater(f["estimated_mse"], 0)
            s, h, exr = self.d.request("GET", "/api/v1/jobs/%s/frames/3/image?format=exr" % jid)
            self.assertEqual(s, 200)
            results[mixer] = exr
            s, h, png = self.d.request("GET", "/api/v1/jobs/%s/frames/3/image?format=png&layer=alpha" % jid)
            self.assertEqual(s, 200)
        self.assertNotEqual(results["closed-form"], results["network"])
        s, b = self.d.json("POST", "/api/v1/jobs", {"name": "mbad", "output": {"dir": self.d.allowed},
                                                   "pipeline": {"mixer": "neural"}})
        self.assert_error(s, b, 400, "invalid_field")
        self.assertIn("network", b["error"]["message"])

    def test_metrics_format(self):
        s, h, body = self.d.request("GET", "/metrics")
        self.assertEqual(s, 200)
        self.assertTrue(h["content-type"].startswith("text/plain; version=0.0.4"))
        text = body.decode()
        types = {}
        sample = re.compile(r'^([a-zA-Z_:][a-zA-Z0-9_:]*)(\{([a-zA-Z_][a-zA-Z0-9_]*="[^"]*",?)*\})? (-?[0-9.e+-]+|\+Inf|NaN)$')
        for line in text.strip().split("\n"):
            if line.startswith("# TYPE"):
                _, _, name, typ = line.split(" ")
                types[name] = typ
                continue
            if line.startswith("# HELP"):
                continue
            self.assertRegex(line, sample)
            name = sample.match(line).group(1)
            base = re.sub(r"_(bucket|sum|count)$", "", name)
            self.assertTrue(name in types or base in types, line)
            self.assertNotIn("frame=", line)  # no per-frame labels
        for name in ("proden_passes_ingested_total", "proden_ingested_bytes_total",
                     "proden_frame_updates_total", "proden_queue_depth", "proden_errors_total",
                     "proden_stage_duration_seconds", "proden_sse_clients"):
            self.assertIn(name, types)
        self.assertEqual(types["proden_stage_duration_seconds"], "histogram")


class AuthTest(unittest.TestCase):
    def test_token_protects_mutations(self):
        with TempRoot() as root:
            d = Daemon(root, token=TOKEN).start()
            try:
                body = {"name": "a", "output": {"dir": os.path.join(d.allowed, "o")}}
                s, b = d.json("POST", "/api/v1/jobs", body, auth=False)
                self.assertEqual(s, 401, b)
                self.assertEqual(b["error"]["code"], "unauthorized")
                s, b = d.json("POST", "/api/v1/jobs", body, headers={"Authorization": "Bearer wrong"})
                self.assertEqual(s, 401)
                s, b = d.json("POST", "/api/v1/jobs", body, headers={"Authorization": "Basic " + TOKEN})
                self.assertEqual(s, 401)
                s, b = d.json("PUT", "/api/v1/jobs/x/frames/1/passes/1", b"x" * 100, auth=False)
                self.assertEqual(s, 401)
                # Reads need the token too unless the operator opens them (open_reads).
                self.assertEqual(d.json("GET", "/api/v1/jobs", auth=False)[0], 401)
                self.assertEqual(d.json("GET", "/metrics", auth=False)[0], 401)
                self.assertEqual(d.json("GET", "/api/v1/jobs")[0], 200)
                self.assertEqual(d.json("GET", "/livez", auth=False)[0], 200)
                self.assertEqual(d.request("GET", "/", auth=False)[0], 200)  # the dashboard's page
                s, b = d.json("POST", "/api/v1/jobs", body)
                self.assertEqual(s, 201, b)
                s, _, _ = d.request("DELETE", "/api/v1/jobs/" + b["id"], auth=False)
                self.assertEqual(s, 401)
            finally:
                self.assertEqual(d.stop(), 0)

    def test_open_reads(self):
        with TempRoot() as root:
            d = Daemon(root, token=TOKEN, config={"open_reads": True}).start()
            try:
                self.assertEqual(d.json("GET", "/api/v1/jobs", auth=False)[0], 200)
                self.assertEqual(d.json("GET", "/metrics", auth=False)[0], 200)
                body = {"name": "a", "output": {"dir": os.path.join(d.allowed, "o")}}
                self.assertEqual(d.json("POST", "/api/v1/jobs", body, auth=False)[0], 401)
            finally:
                self.assertEqual(d.stop(), 0)

    def test_refuses_public_bind_without_token(self):
        with TempRoot() as root:
            os.makedirs(os.path.join(root, "a"))
            r = subprocess.run([BINARY, "serve", "--port", "0", "--bind", "0.0.0.0", "--state-dir",
                                os.path.join(root, "s"), "--allow-root", os.path.join(root, "a")],
                               capture_output=True, timeout=20)
            self.assertEqual(r.returncode, 2, r.stderr)
            self.assertIn(b"token", r.stderr)
            r = subprocess.run([BINARY, "serve", "--port", "0", "--state-dir", os.path.join(root, "s")],
                               capture_output=True, timeout=20)
            self.assertEqual(r.returncode, 2, r.stderr)


class StartupLogTest(unittest.TestCase):
    """The start-up line says how the daemon pages its large blocks (docs/api.md, "Memory")."""

    @staticmethod
    def thp_mode():
        try:
            with open("/sys/kernel/mm/transparent_hugepage/enabled") as f:
                m = re.search(r"\[(\w+)\]", f.read())
                return m.group(1) if m else None
        except OSError:
            return None

    def logged_mode(self, env_off):
        saved = os.environ.get("PRODEN_HUGE_PAGES")
        if env_off:
            os.environ["PRODEN_HUGE_PAGES"] = "off"
        else:
            os.environ.pop("PRODEN_HUGE_PAGES", None)
        try:
            with TempRoot() as root:
                d = Daemon(root).start()
                try:
                    return d.huge_pages()
                finally:
                    self.assertEqual(d.stop(), 0)
        finally:
            if saved is None:
                os.environ.pop("PRODEN_HUGE_PAGES", None)
            else:
                os.environ["PRODEN_HUGE_PAGES"] = saved

    def test_logs_how_large_blocks_are_paged(self):
        want = {"madvise": "advised", "always": "always"}.get(self.thp_mode(), "off")
        default, off = self.logged_mode(env_off=False), self.logged_mode(env_off=True)
        if default == "sanitizer":
            # A sanitizer build keeps its own allocator and says so, whatever the environment.
            self.assertEqual(off, "sanitizer")
        else:
            self.assertEqual(default, want)
            self.assertEqual(off, "off")


if __name__ == "__main__":
    unittest.main(verbosity=2)
