"""Issue 13's daemon features against the real binary: a job target and min_passes; a frame that
converges (SSE `converged` event, frame status, EXR header), keeps taking passes, and un-converges
loudly when a later version misses the target with confidence; `proden wait` and its exit codes;
the version history (GET .../history, the images kept per output.history, image?version=K); output.name's #### frame
padding; renderer AOVs in the published EXR; view_layer; and the convergence state surviving a
restart; and `wait`'s exit code when its own deadline cuts a request short (a stalling peer on
loopback, see StallingDaemon). Passes: the committed Cornell passes (8 x 4 spp) and, to break convergence, one of them
with strong Gaussian noise added (oiiotool). The relMSE target is put between the estimates
`proden denoise --json` gives for 2 and 3 passes, so the frame converges at version 3."""
import http.server
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "clients", "python"))
from harness import BINARY, CORNELL, SAMPLES, Daemon, TempRoot, place_atomic, wait_until  # noqa: E402
from proden_client import Client  # noqa: E402



def cli_estimate(passes):
    with tempfile.TemporaryDirectory() as t:
        r = subprocess.run([BINARY, "denoise", "-q", "--json", "--out", os.path.join(t, "o.exr")]
                           + passes, capture_output=True, text=True, check=True)
    return json.loads(r.stdout)["estimated_error"]


def noisy_pass(src, dst):
    subprocess.run(["oiiotool", src, "--noise:type=gaussian:mean=0:stddev=0.5:mono=0", "-o",
                    dst], check=True, capture_output=True)


def wait_cli(d, *args, timeout=60, url=None):
    r = subprocess.run([BINARY, "wait", "--url", url or d.url] + list(args), capture_output=True,
                       text=True, timeout=timeout)
    return r.returncode, r.stdout, r.stderr


def header(path):
    r = subprocess.run(["oiiotool", "--info", "-v", path], capture_output=True, text=True)
    out = {}
    for line in r.stdout.split("\n"):
        line = line.strip()
        if ": " in line:
            k, v = line.split(": ", 1)
            out[k] = v[1:-1].replace('\\"', '"') if v.startswith('"') else v
        if line.startswith("channel list:"):
            out["channels"] = [c.strip() for c in line.split(":", 1)[1].split(",")]
    return out


class StallingDaemon(http.server.ThreadingHTTPServer):
    """What `proden wait` meets at a daemon that answers, ends its event streams at once and then
    stalls. The real daemon does each of these (a 404 for a frame with no pass, a stream cut at a
    drain, a reply slowed by load) but not on cue, so this peer plays them in order on loopback.
    `stall_after` is how many frame requests it answers before the rest hang."""

    daemon_threads = True

    def __init__(self, stall_after):
        self.stall_after, self.frames, self.streams = stall_after, 0, 0
        self.lock = threading.Lock()
        super().__init__(("127.0.0.1", 0), StallingHandler)
        threading.Thread(target=self.serve_forever, daemon=True).start()

    def close(self):
        self.shutdown()
        self.server_close()

    @property
    def url(self):
        return "http://127.0.0.1:%d" % self.server_address[1]


class StallingHandler(http.server.BaseHTTPRequestHandler):
    def log_message(self, *a):
        pass

    def do_GET(self):
        s = self.server
        if self.path == "/api/v1/events":
            with s.lock:
                s.streams += 1
            self.wfile.write(b"HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\n\r\n"
                             b"retry: 2000\n\n")
            self.close_connection = True
            return
        with s.lock:
            s.frames += 1
            stall = s.frames > s.stall_after
        if stall:
            time.sleep(10)
            return
        body = json.dumps({"error": {"code": "not_found", "message": "no frame 1"}}).encode()
        self.send_response(404)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)


class WaitDeadlineTest(unittest.TestCase):
    def wait_on(self, stall_after):
        """`proden wait --timeout 1` against a StallingDaemon -> (exit code, stderr, the peer)."""
        s = StallingDaemon(stall_after)
        self.addCleanup(s.close)
        rc, _, err = wait_cli(None, "--job", "jfeedfeedfeed", "--frame", "1", "--timeout", "1",
                              url=s.url)
        return rc, err, s

    def test_request_cut_by_the_deadline_is_a_timeout(self):
        # One answer, the stream ends, the next request hangs past the deadline: the daemon was
        # reached, so the wait timed out (4), it did not find the daemon failing (6).
        rc, err, _ = self.wait_on(stall_after=1)
        self.assertEqual(rc, 4, err)
        self.assertIn("timed out", err)

    def test_never_answered_is_unreachable(self):
        rc, err, _ = self.wait_on(stall_after=0)
        self.assertEqual(rc, 6, err)

    def test_ended_streams_are_not_reopened_in_a_tight_loop(self):
        rc, err, s = self.wait_on(stall_after=10 ** 9)
        self.assertEqual(rc, 4, err)
        self.assertGreaterEqual(s.streams, 2)  # it does reconnect
        self.assertLessEqual(s.streams, 8, "event streams opened in 1 s")


class ConvergenceTest(unittest.TestCase):
    def test_target_converge_wait_versions(self):
        with TempRoot() as root:
            d = Daemon(root).start()
            try:
                self.scenario(d)
            except Exception:
                print(d.read_log(), file=sys.stderr)
                raise
            finally:
                if d.proc:
                    d.stop()

    def bad(self, d, body, field):
        s, j = d.json("POST", "/api/v1/jobs", body)
        self.assertEqual(s, 400, j)
        self.assertIn(field, j["error"]["message"])

    def scenario(self, d):
        c = Client(d.url)
        out = os.path.join(d.allowed, "out")
        base = {"name": "x", "output": {"dir": out}}
        self.bad(d, dict(base, target={"relmse": 0}), "target")
        self.bad(d, dict(base, target={"relmse": 1e-3, "equivalent_spp": 64}), "target")
        self.bad(d, dict(base, target={"spp": 64}), "target")
        self.bad(d, dict(base, min_passes=0), "min_passes")
        self.bad(d, dict(base, output={"dir": out, "name": "shot"}), "output.name")
        self.bad(d, dict(base, output={"dir": out, "name": "a_##_##"}), "output.name")
        self.bad(d, dict(base, output={"dir": out, "name": "../x_####"}), "output.name")
        self.bad(d, dict(base, output={"dir": out, "history": -1}), "output.history")

        e2, e3 = cli_estimate(CORNELL[:2]), cli_estimate(CORNELL[:3])
        # A target version 3 meets with confidence and version 2 does not.
        self.assertLess(e3["relmse_high"], e2["relmse_high"], (e2, e3))
        target = {"relmse": (e3["relmse_high"] * e2["relmse_high"]) ** 0.5}
        watch = os.path.join(d.allowed, "shot")
        job = c.create_job({"name": "shot", "renderer": "cycles", "target": target,
                            "min_passes": 3,
                            "watch": {"dir": watch, "pattern": "pass_{pass}/beauty_####.exr"},
                            "output": {"dir": out, "name": "shot_beauty.####", "history": 2}})
        self.assertEqual(job["target"], target)
        self.assertEqual(job["output"]["name"], "shot_beauty.####")
        jid = job["id"]
        put = lambda k, src: place_atomic(src, os.path.join(watch, "pass_%02d" % k,
                                                             "beauty_0001.exr"))

        # Exit codes for scripts: unknown job 5, unreachable daemon 6, timeout 4.
        self.assertEqual(wait_cli(d, "--job", "j000000000000", "--frame", "1", "--timeout", "5")[0], 5)
        rc, _, err = wait_cli(d, "--job", jid, "--frame", "1", "--timeout", "2",
                              url="http://127.0.0.1:9")
        self.assertEqual(rc, 6, err)
        rc, _, err = wait_cli(d, "--job", jid, "--frame", "1", "--timeout", "1.5")
        self.assertEqual(rc, 4, err)
        self.assertEqual(wait_cli(d, "--job", jid, "--frame", "1", "--until", "version>x")[0], 2)

        # A waiter started before any pass: returns once the frame converges (version 3).
        waiter = subprocess.Popen([BINARY, "wait", "--url", d.url, "--job", jid, "--frame", "1",
                                   "--timeout", "120", "--json"], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True)
        for k in range(2):  # one version per pass
            put(k, CORNELL[k])
            f = c.wait(jid, 1, until="version>%d" % k, timeout=60)
        self.assertFalse(f["converged"])          # 2 passes < min_passes, target not met
        self.assertEqual(f["convergence"]["state"], "rendering")
        self.assertIsNone(waiter.poll())
        put(2, CORNELL[2])
        wout, werr = waiter.communicate(timeout=120)
        self.assertEqual(waiter.returncode, 0, werr)
        f = json.loads(wout)
        self.assertTrue(f["converged"])
        self.assertEqual(f["version"], 3)
        conv = f["convergence"]
        self.assertEqual((conv["state"], conv["since_version"], conv["min_passes"]),
                         ("converged", 3, 3))
        self.assertEqual(conv["target"], target)
        self.assertLessEqual(f["estimated_error"]["relmse_high"], target["relmse"])
        self.assertEqual(f["estimated_error"], e3)  # the daemon's estimate is the CLI's
        self.assertEqual(wait_cli(d, "--job", jid, "--frame", "1", "--until", "version>2",
                                  "--timeout", "10")[0], 0)

        # The published EXR: the custom name, the error object and the AOVs beside the result.
        exr = os.path.join(out, "shot_beauty.0001.exr")
        self.assertEqual(f["outputs"][0], exr)
        h = header(exr)
        self.assertEqual(json.loads(h["proden:estimated_error"])["equivalent_spp"],
                         f["estimated_error"]["equivalent_spp"])
        self.assertEqual(h["proden:converged"], "true")
        self.assertIn("A", h["channels"])                        # Combined.A, averaged
        self.assertIn("Debug Sample Count.X", h["channels"])
        self.assertNotIn("Denoising Albedo.R", h["channels"])   # a feature, not an AOV
        self.assertEqual(f["view_layer"], "ViewLayer")
        self.assertEqual(f["view_layers"], ["ViewLayer"])
        self.assertIn({"name": "A", "mode": "mean"}, f["aovs"])

        # Converged frames keep accepting passes; a very noisy pass makes the next version miss
        # the target with confidence: loudly back to rendering.
        put(3, CORNELL[3])
        f = c.wait(jid, 1, until="version>3", timeout=60)
        self.assertTrue(f["converged"])
        noisy = os.path.join(d.root, "noisy.exr")
        noisy_pass(CORNELL[4], noisy)
        put(4, noisy)
        f = c.wait(jid, 1, until="version>4", timeout=60)
        self.assertFalse(f["converged"], f["estimated_error"])
        self.assertGreater(f["estimated_error"]["relmse_low"], target["relmse"])
        self.assertTrue(f["convergence"]["target_missed"])
        hist = [(e["version"], e["event"]) for e in f["convergence"]["history"]]
        self.assertEqual(hist, [(3, "converged"), (5, "unconverged")])
        evs = [ev for ev in c.events(last_event_id=0, timeout=3)
               if ev.type in ("converged", "unconverged") and ev.data["job"] == jid]
        self.assertEqual([(ev.type, ev.data["version"]) for ev in evs],
                         [("converged", 3), ("unconverged", 5)])
        self.assertIn("reason", evs[1].data)
        s, _, body = d.request("GET", "/metrics")
        self.assertIn("proden_frames_converged_total 1", body.decode())
        self.assertIn("proden_frames_unconverged_total 1", body.decode())

        # History: every version, each with its estimate and convergence; images: latest + 2
        # kept; older ones refused by name; a kept one served as it was.
        h = c.history(jid, 1)
        self.assertEqual([e["version"] for e in h], [1, 2, 3, 4, 5])
        self.assertEqual([e["converged"] for e in h], [False, False, True, True, False])
        self.assertEqual(h[-1]["estimated_error"], f["estimated_error"])
        self.assertEqual(c.frame(jid, 1)["versions"], [5, 4, 3])
        kept = lambda v: os.path.join(out, "versions", "shot_beauty.0001.v%04d.exr" % v)
        for v in (5, 4, 3):
            self.assertTrue(os.path.exists(kept(v)), kept(v))
        self.assertFalse(os.path.exists(kept(2)))
        s, hdr, v3 = d.request("GET", "/api/v1/jobs/%s/frames/1/image?version=3" % jid)
        self.assertEqual((s, hdr["x-proden-version"]), (200, "3"))
        self.assertEqual(json.loads(header(kept(3))["proden:estimated_error"]),
                         h[2]["estimated_error"])
        s, hdr, latest = d.request("GET", "/api/v1/jobs/%s/frames/1/image" % jid)
        self.assertEqual((s, hdr["x-proden-version"]), (200, "5"))
        self.assertNotEqual(v3, latest)
        s, j = d.json("GET", "/api/v1/jobs/%s/frames/1/image?version=2" % jid)
        self.assertEqual((s, j["error"]["code"]), (404, "version_not_available"))
        self.assertIn("kept: 5, 4, 3", j["error"]["message"])
        s, j = d.json("GET", "/api/v1/jobs/%s/frames/1/image?version=0" % jid)
        self.assertEqual((s, j["error"]["code"]), (400, "invalid_parameter"))
        s, hdr, png = d.request("GET", "/api/v1/jobs/%s/frames/1/image?version=4&format=png"
                                % jid)
        self.assertEqual((s, png[:4]), (200, b"\x89PNG"))
        self.assertEqual(c.frame(jid, 1)["versions"], [5, 4, 3])

        # The state survives a restart: still unconverged with its history, no event replayed.
        port = d.port
        self.assertEqual(d.stop(), 0)
        d.start(port=port)
        f = c.frame(jid, 1)
        self.assertEqual((f["version"], f["converged"]), (5, False))
        self.assertEqual(len(f["convergence"]["history"]), 2)
        self.assertEqual(c.history(jid, 1)[-1]["version"], 5)

        # A job reading a view layer the passes lack: the pass is refused naming what they have.
        w2 = os.path.join(d.allowed, "vl")
        j2 = c.create_job({"name": "vl", "view_layer": "Foreground",
                           "watch": {"dir": w2, "pattern": "pass_{pass}/beauty_####.exr"},
                           "output": {"dir": os.path.join(d.allowed, "vl_out")}})
        place_atomic(CORNELL[0], os.path.join(w2, "pass_00", "beauty_0001.exr"))
        q = wait_until(lambda: (lambda fr: fr.get("quarantined") or None)(
            c.frame(j2["id"], 1, missing_ok=True) or {}), timeout=30, what="quarantine")
        self.assertEqual(q[0]["kind"], "missing_channels")
        self.assertIn("no view layer 'Foreground' (the file has: ViewLayer)", q[0]["message"])


if __name__ == "__main__":
    unittest.main()
