"""Hostile files against the real daemon (issue 11): bytes that are not UTF-8 in a pass, images of
other formats named .exr, headers declaring gigabytes, watch patterns that make a regex backtrack,
and symlinks or renames swapped in after a path was accepted. Each must be refused with an error
event, leave the daemon serving (/livez within a generous deadline), bounded in memory, inside its
roots, and alive across restarts."""
import json
import os
import socket
import sys
import time
import unittest

sys.path.insert(0, os.path.dirname(__file__))
from harness import CORNELL, FAST_WATCH, Daemon, SseClient, TempRoot  # noqa: E402
import hostile_support as hf  # noqa: E402
from hostile_support import LIVEZ_DEADLINE, vm_hwm_mib  # noqa: E402



def livez_ok(d, timeout=LIVEZ_DEADLINE):
    t0 = time.monotonic()
    s, _, _ = d.request("GET", "/livez", timeout=timeout)
    return s == 200 and time.monotonic() - t0 < timeout


def place(path, data):
    """Writes `data` as a renderer should: a temp name, then a rename."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = os.path.join(os.path.dirname(path), "." + os.path.basename(path) + ".tmp")
    hf.write(tmp, data)
    os.rename(tmp, path)


def error_events(sse, job, count, timeout=30.0):
    """Reads until `count` error events of `job` arrived (raises AssertionError after `timeout`
    seconds, keep-alive comments or not); returns them."""
    got = []
    deadline = time.monotonic() + timeout
    while len(got) < count:
        left = deadline - time.monotonic()
        if left <= 0:
            raise AssertionError("%d of %d error events of %s seen: %r" % (len(got), count, job, got))
        sse.sock.settimeout(left)
        try:
            block = sse._read_until(b"\n\n").decode()
        except socket.timeout:
            continue
        ev = {}
        for line in block.split("\n"):
            k, _, v = line.partition(": ")
            if k == "data":
                ev["data"] = json.loads(v)
            elif k == "event":
                ev["event"] = v
        if ev.get("event") == "error" and ev["data"]["job"] == job:
            got.append(ev["data"])
    return got


class DaemonTest(unittest.TestCase):
    """One daemon per test, in its own temp root; `config` is its config."""
    config = None

    def setUp(self):
        self.tmp = TempRoot()
        self.root = self.tmp.__enter__()
        self.prepare()
        self.d = Daemon(self.root, config=self.config).start()

    def prepare(self):
        pass

    def tearDown(self):
        try:
            if self.d.proc:
                self.assertEqual(self.d.stop(timeout=20), 0)
        finally:
            if sys.exc_info()[0]:
                print(self.d.read_log(), file=sys.stderr)
            self.tmp.__exit__(None, None, None)


class HostileFilesTest(DaemonTest):

    def test_non_utf8_channel_names_and_header_values(self):
        """Class 1: a few hundred bytes that are not UTF-8 must give an error event and a
        persisted quarantine record, not a crash loop."""
        d = self.d
        sse = SseClient(d)
        watch = os.path.join(d.allowed, "w")
        jid = d.create_job("utf8", watch)
        bad_names = hf.exr(channels=(b"\xff\xfe", b"X\xc3\x28", b"Y\x80\x1b[2J"))
        bad_spp = hf.exr(channels=(b"Lay\xff.Combined.B", b"Lay\xff.Combined.G", b"Lay\xff.Combined.R"),
                         extra=[hf.string_attr(b"cycles.Lay\xff.samples", b"\xff\xfe\xfd")])
        bad_value = hf.exr(extra=[hf.string_attr("Software", b"POV-Ray \xff"),
                                  hf.string_attr(b"n\xffote", b"\xed\xa0\x80")])
        self.assertLess(len(bad_names), 1000)
        place(os.path.join(watch, "pass_a", "beauty_0001.exr"), bad_names)
        place(os.path.join(watch, "pass_b", "beauty_0001.exr"), bad_spp)
        errors = error_events(sse, jid, 2)
        for e in errors:
            json.dumps(e, ensure_ascii=False).encode("utf-8")  # valid text all the way
            self.assertTrue(e["quarantined"], e)
        kinds = sorted(e["kind"] for e in errors)
        self.assertEqual(kinds, ["invalid_value", "missing_channels"], errors)
        self.assertIn("\\xff", "".join(e["message"] for e in errors))
        # A file whose odd bytes are only in header values nobody quotes is a good pass.
        place(os.path.join(watch, "pass_c", "beauty_0001.exr"), bad_value)
        d.wait_passes(jid, 1, 1)
        self.assertTrue(livez_ok(d))
        # The quarantine record is on disk, so a restart does not retry (and does not die).
        qfile = os.path.join(d.state, "jobs", jid, "quarantine.json")
        with open(qfile, "rb") as f:
            records = json.loads(f.read().decode("utf-8"))
        self.assertEqual(sorted(r["pass"] for r in records), ["a", "b"])
        sse.close()
        self.assertEqual(d.stop(), 0)
        d.start()
        time.sleep(2.0)  # the crash loop died within half a second of every start
        self.assertIsNone(d.proc.poll())
        self.assertTrue(livez_ok(d))
        s, meta = d.frame(jid, 1)
        self.assertEqual(s, 200)
        self.assertEqual(sorted(q["pass"] for q in meta["quarantined"]), ["a", "b"])
        self.assertEqual(meta["passes"], 1)

    def test_other_image_formats_are_not_passes(self):
        """Class 6: a PNG (or TIFF, ...) named .exr is refused by its magic bytes, watched or
        uploaded; a Radiance file only where the profile reads it."""
        d = self.d
        sse = SseClient(d)
        watch = os.path.join(d.allowed, "pov")
        jid = d.create_job("pov", watch, renderer="povray", spp=1)
        place(os.path.join(watch, "pass_00", "beauty_0001.exr"), hf.exr(width=8, height=8))
        d.wait_passes(jid, 1, 1)
        place(os.path.join(watch, "pass_01", "beauty_0001.exr"), hf.png(8, 8))
        err = error_events(sse, jid, 1)[0]
        self.assertEqual((err["kind"], err["pass"]), ("unsupported_format", "01"), err)
        self.assertIn("PNG", err["message"])
        self.assertEqual(d.frames(jid)[1]["passes"], 1)
        # Uploads: the same check before the body is accepted.
        up = d.create_job("cyc", renderer="cycles")
        s, b = d.json("PUT", "/api/v1/jobs/%s/frames/1/passes/p" % up, hf.png(8, 8))
        self.assertEqual((s, b["error"]["code"]), (400, "invalid_pass"), b)
        self.assertIn("PNG", b["error"]["message"])
        s, b = d.json("PUT", "/api/v1/jobs/%s/frames/1/passes/h" % up, hf.radiance())
        self.assertEqual(s, 400, b)  # Cycles writes EXR only
        s, b = d.json("PUT", "/api/v1/jobs/%s/frames/1/passes/h" % jid, hf.radiance(8, 8))
        self.assertEqual(s, 202, b)  # POV-Ray writes .hdr too
        d.wait_passes(jid, 1, 2)
        sse.close()

    def test_memory_bombs(self):
        """Class 4: small files declaring huge attributes or images are refused from their
        header: no gigabyte allocations, /livez answers meanwhile."""
        d = self.d
        sse = SseClient(d)
        watch = os.path.join(d.allowed, "bombs")
        jid = d.create_job("bombs", watch)
        base = vm_hwm_mib(d)
        bombs = {
            "attr": hf.exr(extra=[b"bomb\0opaque\0" + b"\xff\xff\xff\x7f" + b"x" * 64]),
            "pixels": hf.exr(declared=(12000, 12000), pixels=False, compression=3, pad=2 << 20),
            "zip": hf.exr(declared=(9000, 9000), pixels=False, compression=3, pad=64 << 10),
            "tiles": hf.exr(declared=(8000, 8000), pixels=False, tiles=(1, 1), pad=4096),
            "channels": hf.exr(channels=[b"C%05d" % i for i in range(5000)], pixels=False),
        }
        for i, (name, data) in enumerate(sorted(bombs.items())):
            self.assertLessEqual(len(data), (2 << 20) + 4096, name)
            place(os.path.join(watch, "pass_%s" % name, "beauty_0001.exr"), data)
        deadline = time.monotonic() + 60
        got = []
        while len(got) < len(bombs) and time.monotonic() < deadline:
            self.assertTrue(livez_ok(d), "livez blocked while bombs were read")
            try:
                got += error_events(sse, jid, 1, timeout=0.5)
            except AssertionError:
                pass
        self.assertEqual(len(got), len(bombs), got)
        for e in got:
            self.assertIn(e["kind"], ("too_large", "unreadable", "unsupported_format"), e)
        # Uploads of the same bytes: refused at once.
        up = d.create_job("bombs_up")
        for name, data in bombs.items():
            s, b = d.json("PUT", "/api/v1/jobs/%s/frames/1/passes/%s" % (up, name), data)
            self.assertEqual(s, 400, (name, b))
        self.assertTrue(livez_ok(d))
        grew = vm_hwm_mib(d) - base
        print("bombs: peak RSS grew %.0f MiB" % grew, file=sys.stderr)
        self.assertLess(grew, 300, "the daemon allocated what a bomb declared")
        self.assertNotIn(1, d.frames(jid))
        sse.close()

    def test_pattern_abuse(self):
        """Class 3: patterns that make a backtracking regex spin are bounded or matched in linear
        time: the watcher keeps up, job creation and /livez answer, SIGTERM ends it."""
        d = self.d
        watch = os.path.join(d.allowed, "pat")
        many = "{pass}" * 20 + "{frame}.exr"
        s, b = d.json("POST", "/api/v1/jobs", {"name": "many", "output": {"dir": watch + "_o"},
                                              "watch": {"dir": watch, "pattern": many}})
        self.assertEqual((s, b["error"]["code"]), (400, "invalid_field"), b)
        evil = "{pass}{pass}{pass}{pass}{pass}{pass}{pass}{frame}x.exr"
        jid = d.create_job("evil", watch, pattern=evil)
        os.makedirs(watch, exist_ok=True)
        for name in ("a" * 240, "1" * 240, "a1" * 120, "a" * 200 + "_1_2_3.exr"):
            hf.write(os.path.join(watch, name), b"x")
        time.sleep(1.0)  # a scan and an inotify round
        t0 = time.monotonic()
        other = d.create_job("after_evil", os.path.join(d.allowed, "pat2"))
        self.assertLess(time.monotonic() - t0, 5.0)
        self.assertTrue(livez_ok(d))
        # Matching files are still found (a repeated {pass} matches the same text each time).
        place(os.path.join(watch, "aaaaaaa2x.exr"), hf.exr())
        d.wait_passes(jid, 2, 1)
        t0 = time.monotonic()
        self.assertEqual(d.stop(timeout=20), 0)
        self.assertLess(time.monotonic() - t0, 15.0)
        d.start()
        self.assertTrue(livez_ok(d))
        self.assertEqual(d.json("GET", "/api/v1/jobs/" + other)[0], 200)


class ConfinementTest(DaemonTest):
    """Class 2: paths are confined when used, not only when a job is created."""
    config = {"watch": dict(FAST_WATCH, settle_ms=1500)}

    def prepare(self):
        self.outside = os.path.join(self.root, "outside")
        os.makedirs(os.path.join(self.outside, "pass_01"))
        # The secret differs in size from every pass placed inside: reading it would show.
        self.secret = hf.exr(width=6, height=5, value=9.0)
        hf.write(os.path.join(self.outside, "secret.exr"), self.secret)
        hf.write(os.path.join(self.outside, "pass_01", "beauty_0001.exr"), self.secret)

    def assert_nothing_from_outside(self, jid):
        for n, f in self.d.frames(jid).items():
            s, meta = self.d.frame(jid, n)
            self.assertNotEqual((meta["width"], meta["height"]), (6, 5), "read a file outside")
            for p in meta["pass_list"]:
                self.assertNotEqual(p["size"], len(self.secret), "read a file outside")

    def test_pass_symlink_swapped_after_discovery(self):
        d = self.d
        sse = SseClient(d)
        watch = os.path.join(d.allowed, "w")
        jid = d.create_job("swap", watch)
        inside = os.path.join(d.allowed, "inside.exr")
        hf.write(inside, hf.exr(width=4, height=3))
        target = os.path.join(watch, "pass_01", "beauty_0001.exr")
        os.makedirs(os.path.dirname(target))
        # Discovered as a symlink inside the roots (allowed)...
        tmp = target + ".tmp"
        os.symlink(inside, tmp)
        os.rename(tmp, target)
        time.sleep(0.4)  # found (inotify), settling
        # ... then, before it is read, pointed outside.
        os.symlink(os.path.join(self.outside, "secret.exr"), tmp)
        os.rename(tmp, target)
        err = error_events(sse, jid, 1, timeout=30)[0]
        self.assertEqual(err["kind"], "path_escape", err)
        time.sleep(0.5)
        self.assert_nothing_from_outside(jid)
        sse.close()

    def test_watch_directory_swapped_for_a_symlink(self):
        d = self.d
        sse = SseClient(d)
        watch = os.path.join(d.allowed, "w")
        jid = d.create_job("wswap", watch)
        os.rename(watch, watch + "_old")
        os.symlink(self.outside, watch)
        err = error_events(sse, jid, 1, timeout=30)[0]
        self.assertEqual(err["kind"], "path_escape", err)
        time.sleep(1.0)
        self.assert_nothing_from_outside(jid)
        sse.close()

    def test_watched_subfolder_moved_away(self):
        d = self.d
        watch = os.path.join(d.allowed, "w")
        jid = d.create_job("moved", watch)
        sub = os.path.join(watch, "pass_02")
        os.makedirs(sub)
        place(os.path.join(sub, "beauty_0001.exr"), hf.exr(width=4, height=3))
        d.wait_passes(jid, 1, 1)
        # The watched subfolder leaves the root; a symlink to where it went takes its place, and a
        # pass that would fit the frame appears there (outside the roots).
        moved = os.path.join(self.outside, "moved")
        os.rename(sub, moved)
        os.symlink(moved, sub)
        place(os.path.join(moved, "beauty_0002.exr"), hf.exr(width=4, height=3, value=7.0))
        time.sleep(4.0)  # inotify, several scans and settle times
        frames = d.frames(jid)
        self.assertEqual(frames[1]["passes"], 1)
        self.assertEqual(frames.get(2, {}).get("passes", 0), 0, "read a pass from outside the roots")

    def test_output_directory_swapped_for_a_symlink(self):
        d = self.d
        sse = SseClient(d)
        out = os.path.join(d.allowed, "out")
        jid = d.create_job("oswap", out_dir=out, pipeline={"denoiser": "none"})
        os.rename(out, out + "_old")
        evil = os.path.join(self.outside, "written_here")
        os.makedirs(evil)
        os.symlink(evil, out)
        with open(CORNELL[0], "rb") as f:
            s, b = d.json("PUT", "/api/v1/jobs/%s/frames/1/passes/a" % jid, f.read())
        self.assertEqual(s, 202, b)
        err = error_events(sse, jid, 1, timeout=30)[0]
        self.assertIn(err["kind"], ("publish", "path_escape"), err)
        time.sleep(0.5)
        self.assertEqual(os.listdir(evil), [], "wrote outside the allowed roots")
        s, _, _ = d.request("GET", "/api/v1/jobs/%s/frames/1/image?format=exr" % jid)
        self.assertNotEqual(s, 200)
        sse.close()


if __name__ == "__main__":
    unittest.main(verbosity=2)
