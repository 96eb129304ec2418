"""Issue 11 defect classes against the real daemon: absurd numbers (job spec and config),
concurrent uploads of one pass (idempotency and conflicts), self-ingestion with the output
directory inside the watch directory, and a flipped byte in a frame's state file."""
import json
import os
import subprocess
import sys
import threading
import time
import unittest

sys.path.insert(0, os.path.dirname(__file__))
from harness import SharedDaemonTest, BINARY, CORNELL, SLOWDOWN, Daemon, SseClient, TempRoot, metric, place_atomic, wait_until  # noqa: E402


def read(path):
    with open(path, "rb") as f:
        return f.read()


class RobustnessTest(SharedDaemonTest):

    def test_absurd_spp_refused(self):
        for spp in (1e300, 0, -1, 1e-300, 2e6, "4"):
            s, b = self.d.json("POST", "/api/v1/jobs", {
                "name": "spp", "spp": spp, "output": {"dir": os.path.join(self.d.allowed, "o")}})
            self.assertEqual(s, 400, (spp, b))
            self.assertEqual(b["error"]["code"], "invalid_field")
            self.assertTrue(b["error"]["message"].startswith("spp"), b)
        jid = self.d.create_job("spp_ok", spp=64)
        self.assertEqual(self.d.json("GET", "/api/v1/jobs/" + jid)[1]["spp"], 64)

    def test_concurrent_uploads_of_one_pass(self):
        jid = self.d.create_job("race")
        self.d.json("POST", "/api/v1/jobs/%s/pause" % jid)  # keep the stored upload in place
        bodies = [read(CORNELL[0]), read(CORNELL[1])]
        results = [None] * 16

        def put(i):
            results[i] = self.d.json("PUT", "/api/v1/jobs/%s/frames/1/passes/07" % jid,
                                     bodies[i % 2])

        threads = [threading.Thread(target=put, args=(i,)) for i in range(16)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        accepted = {i % 2 for i, (s, b) in enumerate(results) if s in (200, 202)}
        for i, (s, b) in enumerate(results):
            self.assertIn(s, (202, 409), b)  # queued (first or idempotent) or conflict
        self.assertEqual(len(accepted), 1, results)  # only one body's requests succeed
        winner = accepted.pop()
        stored = os.path.join(self.d.state, "jobs", jid, "uploads", "1", "07.exr")
        self.assertEqual(read(stored), bodies[winner])
        self.d.json("POST", "/api/v1/jobs/%s/resume" % jid)
        f = self.d.wait_passes(jid, 1, 1)
        s, meta = self.d.frame(jid, 1)
        self.assertEqual(meta["pass_list"][0]["size"], len(bodies[winner]))
        # The same bytes once more: already ingested (200); the other bytes: 409.
        s, b = self.d.json("PUT", "/api/v1/jobs/%s/frames/1/passes/07" % jid, bodies[winner])
        self.assertEqual((s, b["status"]), (200, "ingested"), b)
        s, b = self.d.json("PUT", "/api/v1/jobs/%s/frames/1/passes/07" % jid, bodies[1 - winner])
        self.assertEqual((s, b["error"]["code"]), (409, "conflict"), b)
        self.assertEqual(self.d.frames(jid)[1]["passes"], 1)

    def test_output_inside_watch_dir_not_ingested(self):
        watch = os.path.join(self.d.allowed, "selfw")
        jid = self.d.create_job("self", watch, out_dir=watch, pattern="{pass}_{frame}.exr")
        place_atomic(CORNELL[0], os.path.join(watch, "a_0001.exr"))
        wait_until(lambda: self.d.frames(jid).get(1, {}).get("version", 0) >= 1, 30,
                   what="first version")
        self.assertTrue(os.path.exists(os.path.join(watch, "self_0001.exr")))
        time.sleep(2.0)  # several scans (poll 400 ms, settle 250 ms)
        s, meta = self.d.frame(jid, 1)
        self.assertEqual([p["pass"] for p in meta["pass_list"]], ["a"])
        self.assertEqual(meta["quarantined"], [])
        self.assertEqual(meta["version"], 1)


class StateDamageTest(unittest.TestCase):
    def test_flipped_byte_recovers_last_good_state(self):
        with TempRoot() as root:
            d = Daemon(root).start()
            try:
                jid = d.create_job("flip")
                for i, name in enumerate(("a", "b")):
                    s, b = d.json("PUT", "/api/v1/jobs/%s/frames/1/passes/%s" % (jid, name),
                                  read(CORNELL[i]))
                    self.assertEqual(s, 202, b)
                    d.wait_passes(jid, 1, i + 1)
                version = d.frames(jid)[1]["version"]
                self.assertEqual(d.stop(), 0)
                state = os.path.join(d.state, "jobs", jid, "frames", "1.state")
                with open(state, "r+b") as f:  # one byte inside the statistics
                    f.seek(-4096, os.SEEK_END)
                    c = f.read(1)
                    f.seek(-4096, os.SEEK_END)
                    f.write(bytes([c[0] ^ 0x01]))
                d.start()
                sse = SseClient(d, last_event_id=0)
                s, b = d.json("PUT", "/api/v1/jobs/%s/frames/1/passes/c" % jid, read(CORNELL[2]))
                self.assertEqual(s, 202, b)
                f = d.wait_passes(jid, 1, 3, timeout=60)
                s, meta = d.frame(jid, 1)
                self.assertEqual(sorted(p["pass"] for p in meta["pass_list"]), ["a", "b", "c"])
                self.assertGreater(f["version"], version)
                evs = sse.events_until(lambda e: e["event"] == "error"
                                       and e["data"]["kind"] == "corrupt_state", 10)
                self.assertIn("last good state", evs[-1]["data"]["message"])
                sse.close()
                self.assertEqual(d.stop(), 0)
                d.start()  # and it stays recovered
                self.assertEqual(d.frames(jid)[1]["passes"], 3)
            except Exception:
                print(d.read_log(), file=sys.stderr)
                raise
            finally:
                if d.proc:
                    d.stop()


class ConfigBoundsTest(unittest.TestCase):
    def test_absurd_config_numbers_refused(self):
        with TempRoot() as root:
            os.makedirs(os.path.join(root, "a"))
            for cfg, key in (({"worker_threads": 1e300}, "worker_threads"),
                             ({"limits": {"max_upload_bytes": -1}}, "limits.max_upload_bytes"),
                             ({"watch": {"settle_ms": 1e300}}, "watch.settle_ms")):
                path = os.path.join(root, "c.json")
                with open(path, "w") as f:
                    json.dump(cfg, f)
                r = subprocess.run([BINARY, "serve", "--port", "0", "--config", path,
                                    "--state-dir", os.path.join(root, "s"),
                                    "--allow-root", os.path.join(root, "a")],
                                   capture_output=True, timeout=60)
                self.assertEqual(r.returncode, 2, r.stderr)
                self.assertIn(key.encode(), r.stderr)


def signal_blocked(pid, tid, sig):
    """Whether thread `tid` of process `pid` blocks `sig` (/proc's SigBlk mask)."""
    with open("/proc/%d/task/%d/status" % (pid, tid)) as f:
        for line in f:
            if line.startswith("SigBlk:"):
                return bool(int(line.split()[1], 16) >> (sig - 1) & 1)
    return True


class StopSignalTest(unittest.TestCase):
    def test_every_thread_blocks_the_stop_signals(self):
        """Libraries start threads before main() (OpenBLAS's pool, when it is loaded). The
        executable blocks SIGTERM and SIGINT before they do, so every thread of the daemon blocks
        them and the kernel leaves a stop signal for the daemon's signalfd, whichever thread it
        is sent to (docs/api.md, SIGTERM/SIGINT). A handler run on some thread instead could be
        deferred and lost under ThreadSanitizer. Then a SIGTERM sent to one thread (tgkill, the
        main thread: the fd reads what is pending for the process and for the reading thread)
        drains and exits 0, and SIGINT does too."""
        import ctypes
        import signal
        libc = ctypes.CDLL(None, use_errno=True)  # glibc >= 2.30 exports tgkill on every arch
        for sig in (signal.SIGTERM, signal.SIGINT):
            with TempRoot() as root:
                d = Daemon(root).start()
                pid = d.proc.pid
                try:
                    tids = sorted(int(t) for t in os.listdir("/proc/%d/task" % pid))
                    self.assertGreater(len(tids), 2)
                    for s in (signal.SIGTERM, signal.SIGINT):
                        unblocked = [t for t in tids if not signal_blocked(pid, t, s)]
                        self.assertEqual(unblocked, [], "threads not blocking %s" % s.name)
                    self.assertEqual(libc.tgkill(pid, pid, int(sig)), 0)
                    rc = d.proc.wait(timeout=30)
                finally:
                    d.stop()
                self.assertEqual(rc, 0, "the daemon died of %s instead of draining" % sig.name)
                self.assertIn("signal %d: draining" % sig, d.read_log())

    def test_second_signal_while_draining_exits_at_once(self):
        """A second SIGTERM while a frame is still running ends the daemon at once (it dies of the
        signal) and leaves that frame as kill -9 would: after a restart its pass is found again
        and counted once. The pass is a sample frame scaled up so that its run lasts seconds:
        1024x1024, or 384x384 under ThreadSanitizer, where the pipeline runs on one thread and
        ~10x slower."""
        import signal
        with TempRoot() as root:
            big = os.path.join(root, "big.exr")
            size = "384x384" if SLOWDOWN > 1 else "1024x1024"
            subprocess.run(["oiiotool", CORNELL[0], "--resize", size, "-o", big], check=True)
            d = Daemon(root).start()
            try:
                watch = os.path.join(d.allowed, "w")
                jid = d.create_job("drain", watch)
                place_atomic(big, os.path.join(watch, "pass_00", "beauty_0001.exr"))
                wait_until(lambda: metric(d, "proden_frames_in_progress") >= 1, timeout=60,
                           what="the frame's run")
                d.proc.send_signal(signal.SIGTERM)
                wait_until(lambda: "draining" in d.read_log(), what="the drain")
                self.assertGreaterEqual(metric(d, "proden_frames_in_progress"), 1)
                t0 = time.monotonic()
                rc = d.stop(timeout=10)  # the second SIGTERM
                print("second SIGTERM: status %d after %.2f s" % (rc, time.monotonic() - t0))
            except Exception:
                print(d.read_log(), file=sys.stderr)
                raise
            self.assertEqual(rc, -signal.SIGTERM, d.read_log())
            self.assertIn("while draining: exiting now", d.read_log())
            d.start()
            try:
                f = d.wait_passes(jid, 1, 1, timeout=120)
                self.assertEqual((f["passes"], f["version"]), (1, 1))
                self.assertEqual(d.stop(), 0)
            except Exception:
                print(d.read_log(), file=sys.stderr)
                raise


if __name__ == "__main__":
    unittest.main(verbosity=2)
