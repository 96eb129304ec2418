#!/usr/bin/python3
"""How fast a denoiser's error falls with the samples, measured by cross-validation at a quarter and
at half of a frame's passes (docs/error_estimate.md, "Cross-validation": the fixed factor
kHalfToFullMse against an extrapolated rate).

For every scene and level (EVALDATA/<scene>/spp<L>/pass_0k.exr), `proden denoise --aov` runs on the
first K passes (the frame), on its halves A, B (passes alternate) and on the quarters (each half's
passes alternate). With x_h, Var[x_h] a half's render and variance and y_S the denoised image of a
pass set S, all weighted by the reference's relMSE weights w = 1/(ref^2 + 0.01), so that only the
filter's error counts (not the stand-in):
  true     = mean w ((y_frame - ref)^2 - Var[ref])
  half     = mean over h of  mean w ((y_h - x_other)^2 - Var[x_other])
  quarter  = the same with y of each quarter against the other half
  c*pipe   = 1/sqrt(2) x the pipeline's own half-run layers (cvsquare - cvvariance), over true
  rate     = half / quarter (0.5: the error is all variance; 1: all bias)
  extrap   = half x clamp(rate, 0.25, 1), over true

    bench/cv_rate.py --proden build/proden --evaldata /work/evaldata --denoiser nlmeans
"""
import argparse
import glob
import json
import os
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from calibration import denoise, read_rgb as rgb  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--proden", default="build/proden")
    ap.add_argument("--evaldata", default="/work/evaldata")
    ap.add_argument("--denoiser", default="nlmeans")
    ap.add_argument("--scenes", nargs="+", default=["cornell", "glass", "interior", "textured_dof"])
    ap.add_argument("--levels", nargs="+", type=int, default=[8, 16, 32, 64, 128, 256, 512, 1024])
    ap.add_argument("--passes", type=int, default=8)
    ap.add_argument("--json", help="write every cell here")
    a = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="cv_rate_")

    def run(name, passes, denoiser):
        out = os.path.join(tmp, name + ".exr")
        denoise(a.proden, passes, out, denoiser, False)
        return out

    cells = []
    for s in a.scenes:
        r = run("ref_" + s, sorted(glob.glob(f"{a.evaldata}/{s}/reference/pass_*.exr")), "none")
        ref, ref_var = rgb(r, "render."), rgb(r, "variance.")
        w = 1 / (ref * ref + 0.01)
        for level in a.levels:
            p = sorted(glob.glob(f"{a.evaldata}/{s}/spp{level}/pass_*.exr"))[:a.passes]
            A, B = p[0::2], p[1::2]
            sets = {"full": p, "A": A, "B": B, "A0": A[0::2], "A1": A[1::2], "B0": B[0::2],
                    "B1": B[1::2]}
            with ThreadPoolExecutor(2) as ex:
                outs = dict(zip(sets, ex.map(
                    lambda k: run(f"{s}_{level}_{k}", sets[k], a.denoiser), sets)))
            y = rgb(outs["full"], "denoised.")
            true = float(np.mean(w * ((y - ref) ** 2 - ref_var)))
            pipe = float(np.mean(w * (rgb(outs["full"], "cvsquare.") -
                                      rgb(outs["full"], "cvvariance."))))
            lay = {k: (rgb(outs[k], "denoised."), rgb(outs[k], "render."), rgb(outs[k], "variance."))
                   for k in sets if k != "full"}

            def cv(k, other):
                return float(np.mean(w * ((lay[k][0] - lay[other][1]) ** 2 - lay[other][2])))

            half = (cv("A", "B") + cv("B", "A")) / 2
            quarter = (cv("A0", "B") + cv("A1", "B") + cv("B0", "A") + cv("B1", "A")) / 4
            rate = half / quarter if quarter > 0 else float("nan")
            c = {"scene": s, "level": level, "passes": a.passes, "true": true,
                 "c_pipe": 2 ** -0.5 * pipe / true, "rate": rate,
                 "extrap": half * min(max(rate, 0.25), 1.0) / true}
            cells.append(c)
            print("%-12s %5d  true %.4g  c*pipe %.2f  rate %.3f  extrap %.2f" % (
                s, level, true, c["c_pipe"], rate, c["extrap"]), flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(cells, f, indent=1)


if __name__ == "__main__":
    main()
