"""The Flamenco job type end to end without Flamenco: deploy/flamenco/proden_passes.js is compiled
by the Node harness (tests/flamenco/flamenco_harness.js, the documented job-compiler API), then its
tasks are executed in dependency order the way a Flamenco Worker runs the `exec` and
`blender-render` commands ({blender} -> Debian's blender, {blenderArgs} -> "-b -y"), against the
real daemon and real Blender renders of a small Cycles scene. proden must register the job, take
every pass (a repeated seed would be refused as a duplicate) and publish versions; once a frame
has converged, its remaining pass tasks skip the render."""
import json
import os
import shlex
import subprocess
import sys
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.abspath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, os.path.join(REPO, "tests", "service"))
sys.path.insert(0, os.path.join(REPO, "clients", "python"))
from harness import Daemon, TempRoot, wait_until  # noqa: E402
from proden_client import Client  # noqa: E402

JOB_TYPE = os.path.join(REPO, "deploy", "flamenco", "proden_passes.js")
NODE = os.environ.get("NODE", "node")
VARIABLES = {"{blender}": os.environ.get("BLENDER", "blender"), "{blenderArgs}": "-b -y"}


def compile_job(root, name, settings):
    path = os.path.join(root, name + ".settings.json")
    with open(path, "w") as f:
        json.dump(settings, f)
    r = subprocess.run([NODE, os.path.join(HERE, "flamenco_harness.js"), JOB_TYPE, name, path],
                       capture_output=True, text=True, timeout=60)
    if r.returncode != 0:
        raise AssertionError("compile failed: " + r.stderr)
    return json.loads(r.stdout)


def expand(v):
    for k, val in VARIABLES.items():
        v = v.replace(k, val)
    return v


def command_line(cmd):
    """A Worker's command line for the commands this job type uses (Flamenco's command docs)."""
    p = cmd["parameters"]
    if cmd["name"] == "exec":
        return [expand(p["exe"])] + [expand(a) for a in p.get("args", [])]
    if cmd["name"] == "blender-render":
        return ([expand(p["exe"])] + shlex.split(expand(p.get("exeArgs", "")))
                + [expand(a) for a in p.get("argsBefore", [])] + [p["blendfile"]]
                + [expand(a) for a in p.get("args", [])])
    raise AssertionError("unexpected command " + cmd["name"])


def run_tasks(job, only=None):
    """Runs the tasks in an order respecting their dependencies; returns {task: stdout}."""
    done, out = set(), {}
    pending = [t for t in job["tasks"] if only is None or t["name"] in only]
    while pending:
        ready = [t for t in pending if all(d in done or (only and d not in only)
                                           for d in t["dependencies"])]
        assert ready, "dependency cycle among %r" % [t["name"] for t in pending]
        for t in ready:
            text = ""
            for c in t["commands"]:
                r = subprocess.run(command_line(c), capture_output=True, text=True, timeout=600)
                text += r.stdout + r.stderr
                assert r.returncode == 0, "task %s failed:\n%s" % (t["name"], text[-3000:])
            out[t["name"]] = text
            done.add(t["name"])
            pending.remove(t)
    return out


class FlamencoWorkerTest(unittest.TestCase):
    def test_compiled_job_runs(self):
        with TempRoot() as root:
            d = Daemon(root).start()
            try:
                self.scenario(d, root)
            except Exception:
                print(d.read_log(), file=sys.stderr)
                raise
            finally:
                d.stop()

    def scenario(self, d, root):
        blend = os.path.join(root, "cornell.blend")
        subprocess.run([VARIABLES["{blender}"], "-b", "--factory-startup", "-noaudio", "-P",
                        os.path.join(REPO, "samples", "scenes", "cornell.py"), "--", "--seed", "1",
                        "--spp", "1", "--res", "32", "--save-blend", blend],
                       check=True, capture_output=True, timeout=300)
        common = {"render_output_root": d.allowed, "proden_url": d.url, "proden_tools": REPO,
                  "blendfile": blend, "scene": "Scene", "render_engine": "CYCLES", "spp": 2,
                  "python": sys.executable}
        c = Client(d.url)

        # 1. blender-render commands (no skip check): 2 frames x 1 pass.
        job_a = compile_job(root, "flam_a", dict(common, frames="1-2", passes=1,
                                                 skip_converged=False))
        self.assertEqual(len(job_a["tasks"]), 3)
        run_tasks(job_a)
        ja = [j for j in c.jobs() if j["name"] == "flam_a"][0]
        self.assertEqual(ja["watch"]["pattern"], "pass_{pass}/beauty_####.exr")
        frames = wait_until(lambda: (lambda fr: fr if len(fr) == 2 and all(
            f["version"] >= 1 and not f["pending"] for f in fr) else None)(c.frames(ja["id"])),
            timeout=120, what="both frames of flam_a published")
        self.assertEqual(sorted(f["frame"] for f in frames), [1, 2])
        for f in frames:
            self.assertEqual((f["passes"], f["spp"]), (1, 2.0))

        # 2. The wrapper (exec) commands: 1 frame x 3 passes, distinct seeds -> 3 passes taken.
        job_b = compile_job(root, "flam_b", dict(common, frames="5", passes=3, min_passes=2))
        outs = run_tasks(job_b)
        jb = [j for j in c.jobs() if j["name"] == "flam_b"][0]
        f = wait_until(lambda: (lambda fr: fr if fr and fr["passes"] == 3 and not fr["pending"]
                                else None)(c.frame(jb["id"], 5, missing_ok=True)),
                       timeout=120, what="frame 5 of flam_b with 3 passes")
        self.assertEqual(f["quarantined"], [])
        rendered = [n for n, o in outs.items() if "state=rendered" in o]
        self.assertEqual(len(rendered), 3, outs)
        # Re-running the registration task (a requeued Flamenco task) is harmless.
        run_tasks(job_b, only={"proden-register"})
        self.assertEqual(len([j for j in c.jobs() if j["name"] == "flam_b"]), 1)


if __name__ == "__main__":
    unittest.main()
