#!/usr/bin/python3
"""One large frame through the daemon: two uploaded passes of a SIDE x SIDE float RGB EXR, the
time from the first upload until both versions are published, the daemon's stage sums and the
frame's state on disk. Compare binaries in one run (these machines are noisy):
  bench/big_frame.py --binary OLD --binary NEW [--side 2048] [--denoiser none] [--repeat 2]"""
import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "service"))
os.environ.setdefault("PRODEN_SAMPLES_DIR", os.path.join(os.path.dirname(__file__), "..", "samples"))
import harness  # noqa: E402
import hostile_support as hf  # noqa: E402
from daemon_bench import metric_sums  # noqa: E402
from harness import Daemon, TempRoot  # noqa: E402


def one(binary, body, denoiser):
    harness.BINARY = binary  # the binary Daemon starts
    with TempRoot() as root:
        d = Daemon(root).start()
        try:
            jid = d.create_job("big", pipeline={"denoiser": denoiser})
            t0 = time.monotonic()
            for name in ("a", "b"):
                s, r = d.json("PUT", "/api/v1/jobs/%s/frames/1/passes/%s" % (jid, name), body,
                              timeout=600)
                assert s == 202, r
            d.wait_passes(jid, 1, 2, timeout=600)
            wall = time.monotonic() - t0
            stages = {name.split('"')[1]: v for name, v in metric_sums(d).items()
                      if name.startswith("proden_stage_duration_seconds_sum")}
            state = 0
            for dirpath, _, files in os.walk(os.path.join(d.state, "jobs", jid)):
                state += sum(os.path.getsize(os.path.join(dirpath, f)) for f in files)
            return wall, stages, state
        finally:
            d.stop(timeout=120)


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--binary", action="append", required=True)
    ap.add_argument("--side", type=int, default=2048)
    ap.add_argument("--denoiser", default="none")
    ap.add_argument("--repeat", type=int, default=2)
    a = ap.parse_args()
    body = hf.exr(width=a.side, height=a.side, value=0.5)
    print("%dx%d, denoiser %s, 2 uploaded passes of %.1f MB" % (a.side, a.side, a.denoiser,
                                                              len(body) / 1e6))
    for r in range(a.repeat):
        for b in a.binary:
            wall, stages, state = one(b, body, a.denoiser)
            print("%-28s run %d: both versions in %5.2f s; stage sums %s; state on disk %.0f MB"
                  % (b, r + 1, wall, ", ".join("%s %.2f" % kv for kv in sorted(stages.items())),
                     state / 1e6))


if __name__ == "__main__":
    main()
