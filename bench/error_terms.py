#!/usr/bin/python3
"""Where a calibration cell's miss comes from (docs/error_estimate.md): the published estimate
against the truth, and the same model with one part at a time replaced by the reference's.

For every scene, level and input (as bench/calibration.py: 8p, 4p, 2p with the features; hdr), on
the evaluation renders, `proden denoise --aov` runs once; from its layers (x, Var[x], y, alpha,
cvsquare, cvvariance and, for a linear denoiser, cvspread), with e the per-element error
(1-a) v + a m - a (1-a) (y-x)^2 and m the denoiser's error as the pipeline measures it:
  pub     = the published estimated_error.relmse / true
  copy    = this script's copy of it (the 7x7 stand-in, noise-corrected): checks the copy
  refw    = mean e / (ref^2 + 0.01), over true: the stand-in replaced by the reference
  true_m  = the same with m = (y - ref)^2 - Var[ref]: the denoiser's measured error replaced too
  win_ref = mean e / (box7(ref)^2 + 0.01), over true: the reference seen through the window
true as bench/calibration.py: mean ((z - ref)^2 - Var[ref]) / (ref^2 + 0.01). A cell whose
refw is near 1 and pub is not is the stand-in's; win_ref near pub says it is the window's blur.

    /usr/bin/python3 bench/error_terms.py --denoiser gaussian --scenes cornell --levels 8 32 256
"""
import argparse
import glob
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from calibration import CONFIGS, LEVELS, SCENES, read_rgb, reference  # noqa: E402

WINDOW = 7            # the stand-in's window (kStandInRadius = 3)
DRAWS = WINDOW * WINDOW / 4.0  # independent draws per window (kPixelsPerDraw = 4)


def layer(path, name):
    """A layer's RGB, or None when the EXR has no such layer."""
    try:
        return read_rgb(path, name + ".")
    except (SystemExit, ValueError):
        return None


def box(a):
    """Mean over the WINDOW x WINDOW window of each pixel, edges replicated (as box_mean in
    pipeline/src/error_estimate.cpp): running sums along each axis."""
    r = WINDOW // 2
    p = np.pad(a, ((r, r), (r, r), (0, 0)), mode="edge")
    c = np.cumsum(np.pad(p, ((1, 0), (0, 0), (0, 0))), axis=0)
    rows = c[WINDOW:] - c[:-WINDOW]
    c = np.cumsum(np.pad(rows, ((0, 0), (1, 0), (0, 0))), axis=1)
    return (c[:, WINDOW:] - c[:, :-WINDOW]) / (WINDOW * WINDOW)


def cell(proden, passes, no_features, denoiser, ref, ref_var, out):
    cmd = [proden, "denoise", "-q", "--json", "--aov", "--denoiser", denoiser, "--out", out]
    if no_features:
        cmd.append("--no-features")
    r = json.loads(subprocess.run(cmd + passes, check=True, capture_output=True, text=True).stdout)
    z = read_rgb(out)
    x, v, y, a = (layer(out, n) for n in ("render", "variance", "denoised", "alpha"))
    q, vh, spread = (layer(out, n) for n in ("cvsquare", "cvvariance", "cvspread"))
    if y is None or q is None:
        sys.exit("%s: no denoised or cross-validation layers (denoiser none, or one pass)" % out)
    d = y - x
    m = q - vh - spread if spread is not None else (q - vh) / np.sqrt(2.0)
    mix = lambda m_: (1 - a) * v + a * m_ - a * (1 - a) * d * d  # noqa: E731
    e = mix(m)
    w_ref = 1.0 / (ref * ref + 0.01)
    true = float(np.mean(((z - ref) ** 2 - ref_var) * w_ref))
    e_pos = np.maximum(np.maximum(e, (1 - a) ** 2 * v), 0.0)
    stand_in = np.maximum(box(z) ** 2 - box(e_pos) / DRAWS, 0.0)
    return {
        "pub": r["estimated_error"]["relmse"] / true,
        "copy": float(np.mean(e / (stand_in + 0.01))) / true,
        "refw": float(np.mean(e * w_ref)) / true,
        "true_m": float(np.mean(mix((y - ref) ** 2 - ref_var) * w_ref)) / true,
        "win_ref": float(np.mean(e / (box(ref) ** 2 + 0.01))) / true,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--proden", default="build/proden")
    ap.add_argument("--evaldata", default="/work/evaldata")
    ap.add_argument("--denoiser", default="nlmeans")
    ap.add_argument("--scenes", nargs="+", default=SCENES)
    ap.add_argument("--levels", nargs="+", type=int, default=LEVELS)
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS))
    a = ap.parse_args()
    keys = ["pub", "copy", "refw", "true_m", "win_ref"]
    print("| scene | level | input | " + " | ".join(keys) + " |")
    print("|---|---|---|" + "---|" * len(keys))
    with tempfile.TemporaryDirectory() as tmp:
        for scene in a.scenes:
            sdir = os.path.join(a.evaldata, scene)
            ref, ref_var = reference(a.proden, sdir, tmp)
            for level in a.levels:
                found = sorted(glob.glob(os.path.join(sdir, "spp%d" % level, "pass_*.exr")))
                for config in a.configs:
                    n, no_features = CONFIGS[config]
                    if len(found) < max(n, 2):
                        continue
                    out = os.path.join(tmp, "%s_%d_%s.exr" % (scene, level, config))
                    c = cell(a.proden, found[:n], no_features, a.denoiser, ref, ref_var, out)
                    print("| %s | %d | %s | " % (scene, level, config) +
                          " | ".join("%.2f" % c[k] for k in keys) + " |", flush=True)


if __name__ == "__main__":
    main()
