#!/usr/bin/python3
"""Are a frame's passes independent draws around the reference? Per scene and level.

Every error estimate proden makes rests on its passes being independent draws: the variance
between passes, and the cross-validation of a denoiser on one half against the other. This
measures on the evaluation renders (bench/render_eval_set.sh layout) how far that holds:

- `shared`: the covariance between the two halves' renders (passes k even / odd) around the
  reference, over the variance of one half, relMSE-weighted as bench/calibration.py weighs the
  truth, with the reference's own noise (its variance of the mean, from its passes) taken out:
  sum w ((x_A - ref)(x_B - ref) - Var[ref]) / sum w ((x_A - ref)^2 - Var[ref]). 0 for independent halves; the
  share of a half's error the other half repeats otherwise. Its standard error over pixels is
  printed beside it.
- `albedo`: the same for the albedo (unweighted) (the features come from the same sample positions).

A shared part is either a correlation between the passes or a difference between the level's
expectation and the reference (a bias that depends on the spp per pass): no estimate made from
the passes can see it, and a feature-guided denoiser whose features share it keeps it
(docs/error_estimate.md, "What the passes cannot show").

    /usr/bin/python3 bench/pass_independence.py --evaldata /work/evaldata --out \
        bench/results/pass_independence.md
"""
import argparse
import glob
import os

import numpy as np
import OpenImageIO as oiio

SCENES = ["cornell", "textured_dof", "glass", "interior"]
LEVELS = [8, 16, 32, 64, 128, 256, 512, 1024]


def read(path):
    """(RGB, albedo or None) of one pass: Cycles' Combined and Denoising Albedo channels."""
    img = oiio.ImageInput.open(path)
    if img is None:
        raise SystemExit("cannot read %s: %s" % (path, oiio.geterror()))
    names = list(img.spec().channelnames)
    a = img.read_image("float")
    img.close()

    def plane(layer):
        idx = [next((i for i, n in enumerate(names) if n.endswith(layer + "." + c)), None)
               for c in "RGB"]
        return None if None in idx else a[..., idx]

    rgb = plane("Combined")
    return (a[..., :3] if rgb is None else rgb), plane("Denoising Albedo")


def shared(a, b, ref, ref_var, w):
    """Weighted cov(a, b) / var(a) around `ref`, less the reference's own noise `ref_var` (its
    error is in both differences)."""
    ea, eb = a - ref, b - ref
    num = w * (ea * eb - ref_var)
    den = float(np.sum(w * (ea * ea - ref_var)))
    if den <= 0:
        return float("nan"), float("nan")
    n = num.size
    return float(np.sum(num)) / den, float(np.std(num) * np.sqrt(n)) / den


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--evaldata", default="/work/evaldata")
    ap.add_argument("--scenes", nargs="+", default=SCENES)
    ap.add_argument("--levels", nargs="+", type=int, default=LEVELS)
    ap.add_argument("--out", default="bench/results/pass_independence.md")
    a = ap.parse_args()
    rows = []
    for scene in a.scenes:
        refs = sorted(glob.glob(os.path.join(a.evaldata, scene, "reference", "pass_*.exr")))
        if not refs:
            print("%s: no reference, skipped" % scene)
            continue
        ref_rgb = [read(p) for p in refs]
        k = len(refs)
        ref = np.mean([r[0] for r in ref_rgb], axis=0)
        ref_var = np.var([r[0] for r in ref_rgb], axis=0, ddof=1) / k
        ref_alb = alb_var = None
        if ref_rgb[0][1] is not None:
            ref_alb = np.mean([r[1] for r in ref_rgb], axis=0)
            alb_var = np.var([r[1] for r in ref_rgb], axis=0, ddof=1) / k
        w = 1.0 / (ref * ref + 0.01)
        for level in a.levels:
            files = sorted(glob.glob(os.path.join(a.evaldata, scene, "spp%d" % level,
                                                  "pass_*.exr")))
            if len(files) < 2:
                continue
            passes = [read(p) for p in files]
            cols = np.stack([p[0] for p in passes])
            half = [np.mean(cols[h::2], axis=0) for h in (0, 1)]
            sh, se = shared(half[0], half[1], ref, ref_var, w)
            shf = float("nan")
            if ref_alb is not None and passes[0][1] is not None:
                albs = np.stack([p[1] for p in passes])
                ha = [np.mean(albs[h::2], axis=0) for h in (0, 1)]
                shf = shared(ha[0], ha[1], ref_alb, alb_var, np.ones_like(ref_alb))[0]
            spp_pass = level / len(files)
            rows.append((scene, level, len(files), spp_pass, sh, se, shf))
            print("%-12s %5d spp %d passes (%g spp each): shared %.4f +- %.4f  albedo %.4f"
                  % rows[-1], flush=True)
    lines = ["| scene | spp | passes | spp per pass | shared, colour (+- s.e.) | shared, albedo |",
             "|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append("| %s | %d | %d | %g | %.3f +- %.3f | %.3f |" % r)
    os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
    with open(a.out, "w") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
