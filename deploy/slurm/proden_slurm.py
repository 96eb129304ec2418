#!/usr/bin/env python3
"""Slurm integration for proden: render a shot as a job array of independent passes, let proden
publish a better frame after every pass, and stop spending farm time on a frame once proden says
it is good enough (deploy/slurm/README.md).

    proden_slurm.py submit  ...   register the proden job, sbatch the array, optionally monitor
    proden_slurm.py task    ...   one array task (run by proden_pass.sbatch): skip the pass if its
                                  frame has converged, else render it into the watched layout
    proden_slurm.py monitor ...   follow proden's events; scancel a frame's remaining array tasks
                                  when it converges

Array task i renders pass p = i // F of frame frames[i % F] (F frames): passes are pass-major, so
every frame gets its first passes before any frame gets many. Pass p of a frame uses the seed
seed_base + p (distinct per pass, as proden requires) and is written, atomically, to
<watch>/pass_<p, 4 digits>/beauty_<frame, 4 digits>.exr, the pattern the job watches.
Standard library only (plus clients/python/proden_client.py).
"""
import argparse
import json
import os
import shlex
import signal
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
for d in (os.environ.get("PRODEN_CLIENT_DIR"), os.path.join(HERE, "..", "..", "clients", "python")):
    if d and os.path.isfile(os.path.join(d, "proden_client.py")):
        sys.path.insert(0, d)
        break
import proden_client  # noqa: E402

PATTERN = "pass_{pass}/beauty_####.exr"
BLENDER_PASS = os.path.join(HERE, "..", "blender", "proden_pass.py")


def log(*a):
    print("proden_slurm:", *a, file=sys.stderr, flush=True)


def parse_frames(spec):
    """'1-10', '3,5-7', '12' -> sorted list of frame numbers."""
    out = set()
    for part in spec.replace(" ", "").split(","):
        if not part:
            continue
        lo, _, hi = part.partition("-")
        if not lo.isdigit() or (hi and not hi.isdigit()):
            raise argparse.ArgumentTypeError("bad frame range %r" % spec)
        out.update(range(int(lo), int(hi or lo) + 1))
    if not out:
        raise argparse.ArgumentTypeError("empty frame range %r" % spec)
    return sorted(out)


class Layout:
    """The array's task numbering: task i <-> (frame, pass)."""

    def __init__(self, frames, passes):
        self.frames, self.passes = list(frames), int(passes)

    def size(self):
        return len(self.frames) * self.passes

    def task(self, i):
        return self.frames[i % len(self.frames)], i // len(self.frames)

    def tasks_of(self, frame):
        k = self.frames.index(frame)
        return [p * len(self.frames) + k for p in range(self.passes)]


def pass_path(watch, frame, p):
    return os.path.join(watch, "pass_%04d" % p, "beauty_%04d.exr" % frame)


def client_of(a):
    return proden_client.Client(a.url, token_file=a.token_file)


def add_common(p):
    p.add_argument("--url", default=os.environ.get("PRODEN_URL", "http://127.0.0.1:8080"),
                   help="proden serve URL (env PRODEN_URL)")
    p.add_argument("--token-file", default=os.environ.get("PRODEN_TOKEN_FILE"),
                   help="bearer token file (env PRODEN_TOKEN_FILE)")


def add_layout(p):
    p.add_argument("--frames", type=parse_frames, required=True, help="e.g. 1-10 or 3,5-7")
    p.add_argument("--passes", type=int, required=True, help="passes per frame (the budget)")


def add_render(p):
    p.add_argument("--spp", type=int, required=True, help="samples per pass")
    p.add_argument("--seed-base", type=int, default=1, help="pass p uses seed seed_base + p")
    p.add_argument("--blend", help="render this .blend with deploy/blender/proden_pass.py")
    p.add_argument("--blender", default=os.environ.get("BLENDER", "blender"))
    p.add_argument("--blender-args", default="",
                   help="extra proden_pass.py options, e.g. '--threads 1 --view-layer FG'")
    p.add_argument("--render-cmd",
                   help="instead of --blend: a command template with {seed} {spp} {frame} {pass} "
                        "and {out} (an .exr path to write), e.g. for POV-Ray")


# ---- task -------------------------------------------------------------------------------------

def render_command(a, frame, p, out):
    seed = a.seed_base + p
    if a.render_cmd:
        return [s.format(seed=seed, spp=a.spp, frame=frame, out=out, **{"pass": p})
                for s in shlex.split(a.render_cmd)]
    if not a.blend:
        raise SystemExit("proden_slurm: task needs --blend or --render-cmd")
    return ([a.blender, "-b", a.blend, "-noaudio", "-P", os.path.abspath(BLENDER_PASS), "--",
             "--seed", str(seed), "--spp", str(a.spp), "--frame", str(frame), "--out", out]
            + shlex.split(a.blender_args))


def converged(c, job, frame):
    """The frame's convergence, or False when proden cannot say (unreachable daemon: render)."""
    if job is None:
        return False
    try:
        f = c.frame(job, frame, missing_ok=True)
    except proden_client.ProdenError as e:
        if e.status == 0:
            log("proden unreachable (%s); rendering anyway" % e.message)
            return False
        raise
    return bool(f and f.get("converged"))


def job_id_by_name(c, name):
    try:
        for j in c.jobs():
            if j["name"] == name:
                return j["id"]
    except proden_client.ProdenError as e:
        if e.status != 0:
            raise
        log("proden unreachable (%s); rendering anyway" % e.message)
        return None
    raise SystemExit("proden_slurm: no proden job named %s (register it first)" % name)


def cmd_task(a):
    layout = Layout(a.frames, a.passes)
    i = a.index if a.index is not None else int(os.environ.get("SLURM_ARRAY_TASK_ID", "-1"))
    if not 0 <= i < layout.size():
        raise SystemExit("proden_slurm: task index %d outside 0..%d" % (i, layout.size() - 1))
    frame, p = layout.task(i)
    c = client_of(a)
    if a.job is None:
        a.job = job_id_by_name(c, a.job_name)
    t0 = time.monotonic()
    if converged(c, a.job, frame):
        print("PRODEN_TASK index=%d frame=%d pass=%d state=skipped seconds=%.3f"
              % (i, frame, p, time.monotonic() - t0), flush=True)
        return 0
    final = pass_path(a.watch, frame, p)
    if os.path.exists(final):
        print("PRODEN_TASK index=%d frame=%d pass=%d state=exists seconds=0" % (i, frame, p))
        return 0
    os.makedirs(os.path.dirname(final), exist_ok=True)
    tmp = os.path.join(os.path.dirname(final), ".%s.partial.exr" % os.path.basename(final)[:-4])
    cmd = render_command(a, frame, p, tmp)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)

    def cleanup():
        d, stem = os.path.dirname(final), os.path.basename(final)[:-4]
        for n in os.listdir(d):  # ours and the renderer's own temporary names
            if n.startswith("." + stem) and ".partial" in n:
                try:
                    os.remove(os.path.join(d, n))
                except OSError:
                    pass

    def on_term(signum, _frame):  # scancel: stop the renderer, leave no partial file behind
        print("PRODEN_TASK index=%d frame=%d pass=%d state=cancelled seconds=%.3f"
              % (i, frame, p, time.monotonic() - t0), flush=True)
        proc.terminate()
        try:
            proc.wait(2)  # well within Slurm's KillWait
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        cleanup()
        os._exit(128 + signum)

    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, on_term)
    out, _ = proc.communicate()
    if proc.returncode != 0 or not os.path.isfile(tmp) or os.path.getsize(tmp) == 0:
        sys.stdout.write(out.decode(errors="replace")[-4000:])
        log("render failed (exit %s): %s" % (proc.returncode, " ".join(map(shlex.quote, cmd))))
        cleanup()
        return 1
    os.replace(tmp, final)
    print("PRODEN_TASK index=%d frame=%d pass=%d state=rendered seconds=%.3f out=%s"
          % (i, frame, p, time.monotonic() - t0, final), flush=True)
    return 0


# ---- monitor ----------------------------------------------------------------------------------

def remaining_tasks(array_id):
    """Task indices of the array that are still pending or running (squeue)."""
    r = subprocess.run(["squeue", "-h", "-r", "-j", str(array_id), "-o", "%i %T"],
                       capture_output=True, text=True)
    if r.returncode != 0:
        return set()  # the array is gone from the queue
    out = set()
    for line in r.stdout.split("\n"):
        parts = line.split()
        if parts and "_" in parts[0] and parts[0].rsplit("_", 1)[1].isdigit():
            out.add(int(parts[0].rsplit("_", 1)[1]))
    return out


def cancel_frame(array_id, layout, frame, cancel_running=True):
    """scancel the frame's array tasks that are still queued (and running, unless told not to).
    Returns the task indices cancelled."""
    mine = set(layout.tasks_of(frame)) & remaining_tasks(array_id)
    if not cancel_running:
        r = subprocess.run(["squeue", "-h", "-r", "-t", "PENDING", "-j", str(array_id), "-o",
                            "%i"], capture_output=True, text=True)
        pending = {int(x.rsplit("_", 1)[1]) for x in r.stdout.split() if "_" in x}
        mine &= pending
    if mine:
        ids = ["%s_%d" % (array_id, t) for t in sorted(mine)]
        r = subprocess.run(["scancel"] + ids, capture_output=True, text=True)
        log("frame %d converged: scancel %s%s" % (frame, " ".join(ids),
                                                   "" if r.returncode == 0 else
                                                   " (%s)" % r.stderr.strip()))
    return sorted(mine)


def cmd_monitor(a):
    layout = Layout(a.frames, a.passes)
    c = client_of(a)
    done = set()
    # Frames converged before the monitor started.
    for f in layout.frames:
        if converged(c, a.job, f):
            cancel_frame(a.array, layout, f, not a.keep_running)
            done.add(f)
    last = None
    deadline = None if a.timeout is None else time.monotonic() + a.timeout
    while len(done) < len(layout.frames):
        if deadline is not None and time.monotonic() > deadline:
            log("monitor: timeout")
            return 1
        if not remaining_tasks(a.array):
            log("monitor: array %s has no task left" % a.array)
            return 0
        for ev in c.events(last_event_id=last, timeout=a.poll):
            last = ev.id if ev.id is not None else last
            d = ev.data if isinstance(ev.data, dict) else {}
            if ev.type == "converged" and d.get("job") == a.job and d.get("frame") in layout.frames:
                f = d["frame"]
                if f not in done:
                    cancelled = cancel_frame(a.array, layout, f, not a.keep_running)
                    print(json.dumps({"frame": f, "version": d.get("version"),
                                      "cancelled": cancelled}), flush=True)
                    done.add(f)
            if len(done) == len(layout.frames):
                break
    log("monitor: all %d frame(s) converged" % len(done))
    return 0


# ---- submit -----------------------------------------------------------------------------------

def cmd_submit(a):
    layout = Layout(a.frames, a.passes)
    c = client_of(a)
    watch = os.path.abspath(a.watch)
    spec = {"name": a.name, "renderer": a.renderer,
            "watch": {"dir": watch, "pattern": PATTERN},
            "output": {"dir": os.path.abspath(a.output), "formats": ["exr"]}}
    if a.target_relmse is not None:
        spec["target"] = {"relmse": a.target_relmse}
    elif a.target_equivalent_spp is not None:
        spec["target"] = {"equivalent_spp": a.target_equivalent_spp}
    if a.min_passes is not None:
        spec["min_passes"] = a.min_passes
    job = c.ensure_job(spec)
    array = "0-%d" % (layout.size() - 1) + ("%%%d" % a.max_parallel if a.max_parallel else "")
    task_args = ["--url", a.url, "--job", job["id"], "--watch", watch,
                 "--frames", ",".join(map(str, layout.frames)), "--passes", str(layout.passes),
                 "--spp", str(a.spp), "--seed-base", str(a.seed_base)]
    if a.token_file:
        task_args += ["--token-file", os.path.abspath(a.token_file)]
    if a.blend:
        task_args += ["--blend", os.path.abspath(a.blend), "--blender", a.blender]
        if a.blender_args:
            task_args += ["--blender-args", a.blender_args]
    elif a.render_cmd:
        task_args += ["--render-cmd", a.render_cmd]
    else:
        raise SystemExit("proden_slurm: submit needs --blend or --render-cmd")
    env = dict(os.environ, PRODEN_SLURM_DIR=HERE)
    cmd = (["sbatch", "--parsable", "--array", array, "--job-name", "proden-" + a.name,
            "--export", "ALL,PRODEN_SLURM_DIR=" + HERE] + shlex.split(a.sbatch_args)
           + [os.path.join(HERE, "proden_pass.sbatch")] + task_args)
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if r.returncode != 0:
        raise SystemExit("proden_slurm: sbatch failed: %s" % r.stderr.strip())
    array_id = r.stdout.strip().split(";")[0]
    info = {"job": job["id"], "name": a.name, "array": array_id, "tasks": layout.size(),
            "frames": layout.frames, "passes": layout.passes}
    print(json.dumps(info), flush=True)
    if a.monitor:
        ma = argparse.Namespace(url=a.url, token_file=a.token_file, job=job["id"],
                                array=array_id, frames=layout.frames, passes=layout.passes,
                                keep_running=a.keep_running, timeout=None, poll=30.0)
        return cmd_monitor(ma)
    return 0


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)

    s = sub.add_parser("submit", help="register the proden job and sbatch the pass array")
    add_common(s)
    add_layout(s)
    add_render(s)
    s.add_argument("--name", required=True, help="proden job name (unique)")
    s.add_argument("--watch", required=True, help="directory the passes are written to")
    s.add_argument("--output", required=True, help="proden's output directory")
    s.add_argument("--renderer", default="auto", choices=["auto", "cycles", "povray", "generic"])
    g = s.add_mutually_exclusive_group()
    g.add_argument("--target-relmse", type=float)
    g.add_argument("--target-equivalent-spp", type=float)
    s.add_argument("--min-passes", type=int)
    s.add_argument("--max-parallel", type=int, help="array throttle (%%N)")
    s.add_argument("--sbatch-args", default="", help="extra sbatch options")
    s.add_argument("--monitor", action="store_true",
                   help="stay and scancel each frame's remaining tasks when it converges")
    s.add_argument("--keep-running", action="store_true",
                   help="on convergence cancel only queued tasks; let running renders finish")

    t = sub.add_parser("task", help="one array task (SLURM_ARRAY_TASK_ID)")
    add_common(t)
    add_layout(t)
    add_render(t)
    g = t.add_mutually_exclusive_group(required=True)
    g.add_argument("--job", help="proden job id")
    g.add_argument("--job-name", help="proden job name (looked up; e.g. Flamenco tasks, compiled "
                   "before the job is registered)")
    t.add_argument("--watch", required=True)
    t.add_argument("--index", type=int, help="task index (default: SLURM_ARRAY_TASK_ID)")

    m = sub.add_parser("monitor", help="scancel a frame's remaining tasks once it converges")
    add_common(m)
    add_layout(m)
    m.add_argument("--job", required=True, help="proden job id")
    m.add_argument("--array", required=True, help="Slurm array job id")
    m.add_argument("--keep-running", action="store_true")
    m.add_argument("--timeout", type=float, help="give up after this many seconds")
    m.add_argument("--poll", type=float, default=30.0,
                   help="seconds between checks that the array still has tasks")

    a = p.parse_args(argv)
    try:
        return {"submit": cmd_submit, "task": cmd_task, "monitor": cmd_monitor}[a.cmd](a)
    except proden_client.ProdenError as e:
        log(str(e))
        return 2


if __name__ == "__main__":
    sys.exit(main())
