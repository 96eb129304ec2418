"""clients/python/proden_client.py against the real daemon: jobs (ensure_job is idempotent and
refuses another directory under the same name), frames, uploads, errors as ProdenError, SSE with
Last-Event-ID resumption across a daemon restart, and wait() for a version."""
import os
import sys
import threading
import time
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "clients", "python"))
from harness import CORNELL, Daemon, TempRoot, place_atomic  # noqa: E402
import proden_client  # noqa: E402
from proden_client import Client, ProdenError, Timeout  # noqa: E402

TOKEN = "client-test-token-0123456789"


class ClientTest(unittest.TestCase):
    def test_rest_sse_resume_wait(self):
        with TempRoot() as root:
            d = Daemon(root, token=TOKEN).start()
            try:
                self.scenario(d)
            except Exception:
                print(d.read_log(), file=sys.stderr)
                raise
            finally:
                if d.proc:
                    d.stop()

    def scenario(self, d):
        c = Client(d.url, token=TOKEN)
        anon = Client(d.url)
        watch = os.path.join(d.allowed, "w")
        spec = {"name": "cl", "watch": {"dir": watch, "pattern": "pass_{pass}/beauty_####.exr"},
                "output": {"dir": os.path.join(d.allowed, "out")}}

        # Mutations need the token; the error carries status and code.
        with self.assertRaises(ProdenError) as e:
            anon.create_job(spec)
        self.assertEqual((e.exception.status, e.exception.code), (401, "unauthorized"))
        job = c.ensure_job(spec)
        again = c.ensure_job(spec)                       # a re-run task: same job, no 409
        self.assertEqual(job["id"], again["id"])
        other = dict(spec, watch={"dir": os.path.join(d.allowed, "elsewhere"),
                                  "pattern": "pass_{pass}/beauty_####.exr"})
        with self.assertRaises(ProdenError) as e:
            c.ensure_job(other)
        self.assertEqual(e.exception.status, 409)
        jid = job["id"]
        self.assertIn(jid, [j["id"] for j in c.jobs()])
        self.assertEqual(c.job(jid)["name"], "cl")
        self.assertIsNone(c.frame(jid, 1, missing_ok=True))  # no pass yet
        with self.assertRaises(ProdenError) as e:
            c.frame("j000000000000", 1, missing_ok=True)      # a missing *job* is an error
        self.assertEqual(e.exception.status, 404)
        with self.assertRaises(Timeout) as t:
            c.wait(jid, 1, until="version>0", timeout=1.0)
        self.assertIsNone(t.exception.frame)
        with self.assertRaises(ValueError):
            c.wait(jid, 1, until="version>x", timeout=1.0)

        # SSE: the first pass produces a frame event; remember its id.
        events = []
        place_atomic(CORNELL[0], os.path.join(watch, "pass_00", "beauty_0001.exr"))
        for ev in c.events(timeout=30):
            events.append(ev)
            if ev.type == "frame" and ev.data["job"] == jid:
                break
        first = events[-1]
        self.assertEqual(first.data["version"], 1)
        self.assertIsInstance(first.id, int)
        self.assertEqual(c.wait(jid, 1, until="version>0", timeout=30)["version"], 1)

        # Upload a pass over REST while nobody listens; resuming from the first event's id
        # replays the missed one, not the old one.
        r = c.upload_pass(jid, 1, "up1", CORNELL[1])
        self.assertEqual(r["status"], "queued")
        self.assertEqual(c.wait(jid, 1, until="version>1", timeout=30)["passes"], 2)
        got = []
        for ev in c.events(last_event_id=first.id, timeout=10):
            got.append(ev)
            if ev.type == "frame":
                break
        self.assertGreater(got[-1].id, first.id)
        self.assertEqual(got[-1].data["version"], 2)
        # The same bytes again are the same request (idempotent); other bytes conflict.
        self.assertEqual(c.upload_pass(jid, 1, "up1", CORNELL[1])["status"], "ingested")
        with self.assertRaises(ProdenError) as e:
            c.upload_pass(jid, 1, "up1", CORNELL[2])
        self.assertEqual(e.exception.status, 409)

        # A reader following events across a daemon restart on the same port: it reconnects,
        # resumes and sees the version published after the restart.
        seen = []
        done = threading.Event()

        def follow():
            for ev in c.events(last_event_id=got[-1].id, timeout=60):
                seen.append(ev)
                if ev.type == "frame" and ev.data.get("version") == 3:
                    done.set()
                    return

        th = threading.Thread(target=follow, daemon=True)
        th.start()
        time.sleep(0.5)
        port = d.port
        self.assertEqual(d.stop(), 0)
        d.start(port=port)
        place_atomic(CORNELL[2], os.path.join(watch, "pass_02", "beauty_0001.exr"))
        self.assertTrue(done.wait(60), "the follower did not resume: %r" % seen)
        th.join(5)
        frame = c.frame(jid, 1)
        self.assertEqual((frame["version"], frame["passes"]), (3, 3))

        # The published image, and the CLI's exit code for a frame without passes.
        exr = c.image(jid, 1)
        self.assertEqual(exr[:4], b"\x76\x2f\x31\x01")  # OpenEXR magic
        # (reads need the token too: docs/api.md, open_reads)
        tf = os.path.join(d.root, "token")
        self.assertEqual(proden_client.main(["--url", d.url, "frame", jid, "1"]), 2)
        self.assertEqual(proden_client.main(["--url", d.url, "--token-file", tf,
                                             "frame", jid, "9"]), 3)
        c.delete_job(jid)
        with self.assertRaises(ProdenError) as e:
            c.job(jid)
        self.assertEqual(e.exception.status, 404)


if __name__ == "__main__":
    unittest.main()
