"""Issue 13's acceptance test for the calibrated error: a frame fed HDR-only POV-Ray passes must not
report itself converged while its true error is 10x the target.

Real passes are rendered with Debian's povray (samples/render_povray.sh: 1 sample per pixel, no
features, no sample count in the file) and fed to the real daemon twice: job `truth` without a
target, to measure the true relMSE of the final version against the committed 256-pass reference
(samples/renders/povray/reference.exr), and job `target` with a relMSE target 12.5x below that
(10x, with 25 % allowed for the reference's own noise). Every version of `target` has a true error
at least that of the final one, so none may be reported converged: no `converged` event, and the
frame status says `converged: false`.

STATUS: the point estimate is still uncalibrated (on these passes ~270x below the true relMSE);
the test passes because the decision reads the interval's high end, which the frame-wide noise
scope (POV-Ray: 15 degrees of freedom for the whole frame), the absolute sampling error of the
pixel average and the consistency rule keep above the target. With the naive rule (converged when
the point estimate meets the target) it fails: converged at version 2 with the true error 125x the
target (checked by hand). Registered in CTest under the label `farm`; the calibration must keep it
passing (docs/error_estimate.md).
"""
import json
import os
import subprocess
import sys
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.abspath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, os.path.join(REPO, "tests", "service"))
sys.path.insert(0, os.path.join(REPO, "clients", "python"))
from harness import BINARY, Daemon, TempRoot, place_atomic  # noqa: E402
from proden_client import Client  # noqa: E402

PASSES = int(os.environ.get("PRODEN_POV_PASSES", "16"))
REFERENCE = os.path.join(REPO, "samples", "renders", "povray", "reference.exr")


def render_passes(outdir, passes):
    """Real POV-Ray passes 0..passes-1 at the reference's 128x128 (samples/render_povray.sh)."""
    subprocess.run([os.path.join(REPO, "samples", "render_povray.sh"), outdir, str(passes)],
                   check=True, capture_output=True, timeout=1200, env=dict(os.environ, RES="128"))
    return [os.path.join(outdir, "pass_%02d.exr" % k) for k in range(passes)]


def true_relmse(path):
    r = subprocess.run([BINARY, "eval", "--json", "--ref", REFERENCE, path], capture_output=True,
                       text=True, check=True)
    return json.loads(r.stdout)["results"][0]["relmse"]


class PovrayConvergence(unittest.TestCase):
    def test_hdr_only_povray_not_converged_at_10x_true_error(self):
        with TempRoot(prefix="proden-pov-") as root:
            files = render_passes(os.path.join(root, "renders"), PASSES)
            d = Daemon(root).start()
            try:
                self.scenario(d, files)
            except Exception:
                print(d.read_log(), file=sys.stderr)
                raise
            finally:
                d.stop()

    def feed(self, d, c, name, files, **extra):
        watch = os.path.join(d.allowed, name)
        job = c.create_job(dict({"name": name, "renderer": "povray", "spp": 1,
                                 "watch": {"dir": watch, "pattern": "pass_{pass}/beauty_####.exr"},
                                 "output": {"dir": os.path.join(d.allowed, name + "_out")}},
                                **extra))
        status = None
        for k, f in enumerate(files):  # one version per pass, as a farm delivers them
            place_atomic(f, os.path.join(watch, "pass_%02d" % k, "beauty_0001.exr"))
            status = c.wait(job["id"], 1, until="version>%d" % k, timeout=120)
        return job["id"], status

    def scenario(self, d, files):
        c = Client(d.url)
        _, final = self.feed(d, c, "truth", files)
        self.assertEqual(final["passes"], len(files))
        self.assertEqual(final["inputs"], "HDR")
        truth = true_relmse(final["outputs"][0])
        target = truth / 12.5
        est = final["estimated_error"]
        print("HDR-only POV-Ray, %d passes: true relMSE %.4g; estimate %.4g [%s, %s]; target %.4g"
              % (len(files), truth, est["relmse"], est["relmse_low"], est["relmse_high"], target),
              file=sys.stderr)

        jid, last = self.feed(d, c, "target", files, target={"relmse": target}, min_passes=2)
        converged = [ev for ev in c.events(last_event_id=0, timeout=5)
                     if ev.type == "converged" and ev.data.get("job") == jid]
        self.assertEqual(converged, [], "reported converged while its true relMSE is >= 10x the "
                         "target: %r" % [ev.data for ev in converged])
        self.assertFalse(last["converged"])
        self.assertEqual(last["convergence"]["state"], "rendering")


if __name__ == "__main__":
    unittest.main()
