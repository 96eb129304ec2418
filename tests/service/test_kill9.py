"""Crash safety of `proden serve`: the real daemon is killed with SIGKILL at random moments while
passes arrive, and restarted, many times; the final frame must be bit-identical (state digest and
published EXR bytes) to an uninterrupted run, with every pass counted exactly once."""
import os
import random
import subprocess
import sys
import time
import unittest

sys.path.insert(0, os.path.dirname(__file__))
from harness import CORNELL, Daemon, TempRoot, place_atomic  # noqa: E402

TRIALS = int(os.environ.get("PRODEN_KILL_TRIALS", "16"))


def final_frame(d, jid):
    f = d.wait_passes(jid, 1, len(CORNELL), timeout=60)
    s, meta = d.frame(jid, 1)
    s, h, exr = d.request("GET", "/api/v1/jobs/%s/frames/1/image?format=exr" % jid)
    assert s == 200
    path = os.path.join(d.root, "final.exr")
    with open(path, "wb") as fh:
        fh.write(exr)
    return f, meta, path


def same_pixels(a, b):
    """Every channel bit-identical (the EXR header's DateTime differs between writes)."""
    r = subprocess.run(["idiff", "-a", "-fail", "0", "-warn", "0", a, b], capture_output=True)
    return r.returncode == 0


class KillNineTest(unittest.TestCase):
    def test_kill9_during_ingestion(self):
        seed = int(os.environ.get("PRODEN_KILL_SEED", str(int(time.time()))))
        rng = random.Random(seed)
        print("kill -9 trials: %d, seed %d" % (TRIALS, seed), file=sys.stderr)
        with TempRoot() as root:
            # Uninterrupted reference run.
            os.makedirs(os.path.join(root, "ref"))
            ref = Daemon(os.path.join(root, "ref")).start()
            watch = os.path.join(ref.allowed, "w")
            jid = ref.create_job("shot", watch)
            for i, p in enumerate(CORNELL):
                place_atomic(p, os.path.join(watch, "pass_%02d" % i, "beauty_0001.exr"))
                time.sleep(0.05)
            ref_f, ref_meta, ref_exr = final_frame(ref, jid)
            self.assertEqual(ref.stop(), 0)

            # The same passes with SIGKILLs at random moments.
            kroot = os.path.join(root, "kill")
            os.makedirs(kroot)
            d = Daemon(kroot)
            watch = os.path.join(d.allowed, "w")
            placed = 0
            jid = None
            kills = 0
            for trial in range(TRIALS):
                d.start()
                try:
                    if jid is None:
                        jid = d.create_job("shot", watch)
                    for _ in range(rng.choice([0, 1, 1, 1, 2])):
                        if placed < len(CORNELL):
                            place_atomic(CORNELL[placed],
                                         os.path.join(watch, "pass_%02d" % placed, "beauty_0001.exr"))
                            placed += 1
                    # Around the settle time, so kills land before, during and after ingestion.
                    time.sleep(rng.uniform(0.0, 0.8) if trial % 2 else rng.uniform(0.25, 0.45))
                except Exception:
                    print(d.read_log(), file=sys.stderr)
                    raise
                d.kill9()
                kills += 1
            while placed < len(CORNELL):
                place_atomic(CORNELL[placed], os.path.join(watch, "pass_%02d" % placed, "beauty_0001.exr"))
                placed += 1
            d.start()
            try:
                f, meta, exr = final_frame(d, jid)
                self.assertEqual(f["passes"], len(CORNELL))
                self.assertEqual(sorted(p["pass"] for p in meta["pass_list"]),
                                 ["%02d" % i for i in range(len(CORNELL))])
                self.assertEqual(meta["quarantined"], [])
                self.assertEqual(f["spp"], ref_f["spp"])
                self.assertEqual(meta["state_digest"], ref_meta["state_digest"])
                self.assertTrue(same_pixels(exr, ref_exr))
                self.assertTrue(same_pixels(meta["outputs"][0], ref_exr))
            except Exception:
                print(d.read_log(), file=sys.stderr)
                raise
            finally:
                d.stop()
            # Temp files of writes the kills interrupted are gone. Looked at once the daemon has
            # stopped: while it runs, an idle daemon rewrites the published file compressed
            # (output.compression auto) through a temp file of its own.
            leftovers = [n for n in os.listdir(os.path.dirname(meta["outputs"][0])) if n.startswith(".")]
            self.assertEqual(leftovers, [])
            print("kill -9: %d kills, final frame bit-identical (digest %s), %d passes counted once"
                  % (kills, meta["state_digest"], f["passes"]), file=sys.stderr)


if __name__ == "__main__":
    unittest.main(verbosity=2)
