"""Ingestion from a watched directory against the real daemon: slow, partial and placeholder
writes, temp names, unreadable files (quarantined, not retried forever), new subdirectories,
SSE frame events with Last-Event-ID resumption, restart persistence and polling-only mode."""
import os
import shutil
import sys
import time
import unittest

sys.path.insert(0, os.path.dirname(__file__))
from harness import CORNELL, FAST_WATCH, Daemon, SseClient, TempRoot, metric, place_atomic, wait_until  # noqa: E402


def slow_write(src, dst, chunks=4, pause=0.08):
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    with open(src, "rb") as f:
        data = f.read()
    step = len(data) // chunks + 1
    with open(dst, "wb") as f:
        for i in range(0, len(data), step):
            f.write(data[i:i + step])
            f.flush()
            time.sleep(pause)


class IngestTest(unittest.TestCase):
    def test_watch_sse_restart(self):
        with TempRoot() as root:
            cfg = {"watch": dict(FAST_WATCH, max_attempts=3)}
            d = Daemon(root, config=cfg).start()
            try:
                self.run_scenario(d, root, cfg)
            except Exception:
                print(d.read_log(), file=sys.stderr)
                raise
            finally:
                if d.proc:
                    d.stop()

    def run_scenario(self, d, root, cfg):
        watch = os.path.join(d.allowed, "renders")
        sse = SseClient(d)
        self.assertIn("200", sse.status_line)
        self.assertIn("text/event-stream", sse.headers)
        jid = d.create_job("shot010", watch)
        w = lambda p, f=1: os.path.join(watch, "pass_%s" % p, "beauty_%04d.exr" % f)

        # 1. Written slowly in chunks (each pause shorter than the settle time): read once, whole.
        slow_write(CORNELL[0], w("00"))
        f = d.wait_passes(jid, 1, 1)
        s, meta = d.frame(jid, 1)
        self.assertEqual(meta["pass_list"][0]["size"], os.path.getsize(CORNELL[0]))
        events = sse.events_until(lambda e: e["event"] == "frame")
        self.assertEqual(events[0]["event"], "job")
        first_frame_event = events[-1]
        self.assertEqual(first_frame_event["data"]["version"], 1)
        self.assertEqual(first_frame_event["data"]["passes"], 1)

        # 2. A zero-byte placeholder is ignored until the renderer fills it.
        os.makedirs(os.path.dirname(w("01")))
        open(w("01"), "wb").close()
        # 3. Temp names are never read, even with valid content.
        os.makedirs(os.path.dirname(w("02")))
        for name in (".beauty_0001.exr", "beauty_0001.exr.tmp", "beauty_0001.exr~",
                     "beauty_0001.exr.partial"):
            shutil.copyfile(CORNELL[2], os.path.join(watch, "pass_02", name))
        time.sleep(1.2)  # > settle + poll interval
        self.assertEqual(d.frames(jid)[1]["passes"], 1)
        shutil.copyfile(CORNELL[1], w("01") + ".tmp")
        os.rename(w("01") + ".tmp", w("01"))
        os.rename(os.path.join(watch, "pass_02", ".beauty_0001.exr"), w("02"))
        d.wait_passes(jid, 1, 3)

        # 4. Partially written, stalled longer than the settle time, then completed.
        with open(CORNELL[3], "rb") as f:
            data = f.read()
        os.makedirs(os.path.dirname(w("03")))
        with open(w("03"), "wb") as f:
            f.write(data[: len(data) // 2])
        time.sleep(0.5)
        with open(w("03"), "ab") as f:
            f.write(data[len(data) // 2:])
        d.wait_passes(jid, 1, 4)

        # 5. An unreadable file: quarantined with an error event after max_attempts, then left alone.
        os.makedirs(os.path.dirname(w("04")))
        with open(w("04"), "wb") as f:
            f.write(b"\x76\x2f\x31\x01" + b"\x00garbage" * 1000)
        evs = sse.events_until(lambda e: e["event"] == "error" and e["data"]["pass"] == "04", 20)
        err = evs[-1]["data"]
        self.assertEqual((err["kind"], err["quarantined"], err["frame"]), ("unreadable", True, 1))
        self.assertGreaterEqual(metric(d, 'proden_errors_total{kind="unreadable"}'), 1)
        s, meta = d.frame(jid, 1)
        self.assertEqual([q["pass"] for q in meta["quarantined"]], ["04"])
        quarantines = metric(d, 'proden_errors_total{kind="unreadable"}')
        time.sleep(1.2)
        self.assertEqual(metric(d, 'proden_errors_total{kind="unreadable"}'), quarantines)
        self.assertEqual(d.frames(jid)[1]["passes"], 4)

        # 6. A second frame in a directory created now.
        place_atomic(CORNELL[5], w("05", 2))
        d.wait_passes(jid, 2, 1)
        frames = d.frames(jid)
        self.assertEqual(sorted(frames), [1, 2])
        self.assertTrue(os.path.isfile(os.path.join(d.allowed, "shot010_out", "shot010_0001.exr")))

        # SSE resumption: reconnecting with the first frame event's id replays exactly what came
        # after it.
        sse.events_until(lambda e: e["event"] == "frame" and e["data"]["frame"] == 2)
        after = [e for e in sse.all if int(e["id"]) > int(first_frame_event["id"])]
        self.assertGreaterEqual(len(after), 4)
        sse.close()
        sse2 = SseClient(d, last_event_id=first_frame_event["id"])
        replay = [sse2.next_event() for _ in range(len(after))]
        self.assertEqual([e["id"] for e in replay], [e["id"] for e in after])
        self.assertTrue(all(int(e["id"]) > int(first_frame_event["id"]) for e in replay))
        sse2.close()
        ingested = metric(d, "proden_passes_ingested_total")
        self.assertEqual(ingested, 5)

        # Restart (SIGTERM drains and exits 0): nothing lost, nothing counted twice.
        before = {n: d.frame(jid, n)[1] for n in (1, 2)}
        self.assertEqual(d.stop(), 0)
        d.config["watch"] = dict(cfg["watch"], inotify=False)  # and now polling only
        d.start()
        time.sleep(1.5)
        for n in (1, 2):
            s, after_meta = d.frame(jid, n)
            for k in ("passes", "spp", "version", "state_digest", "pass_list", "quarantined"):
                self.assertEqual(after_meta[k], before[n][k], k)
        self.assertEqual(metric(d, "proden_passes_ingested_total"), 0)
        place_atomic(CORNELL[6], w("06"))  # seen by the polling scan
        f = d.wait_passes(jid, 1, 5)
        self.assertEqual(f["version"], before[1]["version"] + 1)
        self.assertEqual(metric(d, "proden_passes_ingested_total"), 1)
        self.assertEqual(d.stop(), 0)


if __name__ == "__main__":
    unittest.main(verbosity=2)
