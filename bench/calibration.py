#!/usr/bin/python3
"""Calibration of the published estimated error (issue 13, docs/error_estimate.md): est/true relMSE
per scene, level, denoiser and input, on the evaluation renders (bench/render_eval_set.sh).

For every scene and level L >= 8 spp (EVALDATA/<scene>/spp<L>/pass_0k.exr, 8 passes of L/8 spp)
and every denoiser, `proden denoise --json --aov` runs on
  - all 8 passes ("8p"), with the features;
  - the first 2 and the first 4 passes ("2p", "4p": spp 2L/8, 4L/8), with the features;
  - all 8 passes with --no-features ("hdr": HDR only).
est = estimated_error.relmse (with its 95 % interval); true = the result's relMSE against the
reference (EVALDATA/<scene>/reference, 8 x 512 spp: its mean), with the reference's own noise
(its variance of the mean, from its 8 passes) taken out:
    true = mean_j ((z_j - ref_j)^2 - Var[ref_j]) / (ref_j^2 + 0.01)      (z: the result, RGB)
The bar (issue 13): est/true in [0.67, 1.5] for every cell from 8 spp; "covered" = the true value
lies in [relmse_low, relmse_high]. The truth has an error of its own, from the reference's noise:
its standard error `true_se` is the jackknife over the reference's 8 passes (true recomputed with
each pass left out), and a cell whose bar verdict changes within true +- 2 true_se is marked (r).

    nice bench/calibration.py --proden build/proden --evaldata /work/evaldata \\
        --denoisers none nlmeans --out bench/results/calibration

Writes <out>.json (every cell) and <out>.md (the table included in bench/RESULTS.md).
`--merge A.json B.json ...` runs nothing and writes <out> from earlier runs' cells (a scene per
run, as each scene's renders finish; with --denoisers, only theirs).
"""
import argparse
import glob
import json
import math
import os
import subprocess
import sys
import tempfile

import numpy as np
import OpenImageIO as oiio

SCENES = ["cornell", "glass", "interior", "textured_dof"]
LEVELS = [8, 16, 32, 64, 128, 256, 512, 1024]
CONFIGS = {"8p": (8, False), "4p": (4, False), "2p": (2, False), "hdr": (8, True)}
BAR = (0.67, 1.5)


def read_rgb(path, prefix=""):
    img = oiio.ImageBuf(path)
    if img.has_error:
        sys.exit("cannot read %s: %s" % (path, img.geterror()))
    names = list(img.spec().channelnames)
    px = img.get_pixels(oiio.FLOAT)
    return np.stack([px[:, :, names.index(prefix + c)] for c in "RGB"], axis=-1).astype(np.float64)


def denoise(proden, passes, out, denoiser, no_features):
    cmd = [proden, "denoise", "-q", "--json", "--aov", "--denoiser", denoiser, "--out", out]
    if no_features:
        cmd.append("--no-features")
    r = subprocess.run(cmd + passes, check=True, capture_output=True, text=True)
    return json.loads(r.stdout)


def reference_passes(scene_dir):
    """The reference's passes, RGB (Cycles' Combined), as one array (passes, H, W, 3)."""
    out = []
    for path in sorted(glob.glob(os.path.join(scene_dir, "reference", "pass_*.exr"))):
        img = oiio.ImageBuf(path)
        names = list(img.spec().channelnames)
        rgb = [n for c in "RGB" for n in names if n.endswith("Combined." + c)]
        if len(rgb) != 3:
            sys.exit("%s: no Combined.R/G/B channels" % path)
        px = img.get_pixels(oiio.FLOAT)
        out.append(np.stack([px[:, :, names.index(n)] for n in rgb], axis=-1).astype(np.float64))
    return np.stack(out)


def true_se(z, passes):
    """Jackknife standard error of the true relMSE over the reference's passes: the truth
    recomputed with each pass left out (its mean and variance of the mean from the others)."""
    n = len(passes)
    if n < 3:
        return math.nan
    total = passes.sum(axis=0)
    sq_total = (passes * passes).sum(axis=0)
    t = []
    for i in range(n):
        s1, s2 = total - passes[i], sq_total - passes[i] * passes[i]
        m = s1 / (n - 1)
        var_mean = np.maximum(s2 - (n - 1) * m * m, 0.0) / (n - 2) / (n - 1)
        t.append(float(np.mean(((z - m) ** 2 - var_mean) / (m * m + 0.01))))
    t = np.array(t)
    return float(math.sqrt((n - 1) / n * np.sum((t - t.mean()) ** 2)))


def verdict_unsure(c):
    """Does the bar's verdict on this cell change with the truth anywhere in true +- 2 se?"""
    se = c.get("true_se")
    if se is None or not math.isfinite(se):
        return False
    lo_true, hi_true = c["true"] - 2 * se, c["true"] + 2 * se
    inside = BAR[0] <= c["ratio"] <= BAR[1]
    r_lo = c["est"] / hi_true if hi_true > 0 else math.inf
    r_hi = c["est"] / lo_true if lo_true > 0 else math.inf
    return any((BAR[0] <= r <= BAR[1]) != inside for r in (r_lo, r_hi))


def reference(proden, scene_dir, tmp):
    """The reference's mean and variance of the mean (proden's own accumulation, denoiser none)."""
    out = os.path.join(tmp, "ref_%s.exr" % os.path.basename(scene_dir.rstrip("/")))
    denoise(proden, sorted(glob.glob(os.path.join(scene_dir, "reference", "pass_*.exr"))), out,
            "none", False)
    return read_rgb(out, "render."), read_rgb(out, "variance.")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--proden", default="build/proden")
    ap.add_argument("--evaldata", default="/work/evaldata")
    ap.add_argument("--scenes", nargs="+", default=SCENES)
    ap.add_argument("--levels", nargs="+", type=int, default=LEVELS)
    ap.add_argument("--denoisers", nargs="+", default=None,
                    help="default none nlmeans; with --merge, keep only these denoisers' cells")
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS))
    ap.add_argument("--out", default="bench/results/calibration")
    ap.add_argument("--merge", nargs="+", metavar="JSON",
                    help="write <out> from these runs' cells instead of running")
    a = ap.parse_args()
    if a.merge:
        cells = [c for path in a.merge for c in json.load(open(path))
                 if a.denoisers is None or c["denoiser"] in a.denoisers]
        denoisers = list(dict.fromkeys(c["denoiser"] for c in cells))
        configs = [k for k in CONFIGS if any(c["config"] == k for c in cells)]
        return write(cells, a.out, denoisers, configs)
    a.denoisers = a.denoisers or ["none", "nlmeans"]
    cells = []
    with tempfile.TemporaryDirectory() as tmp:
        for scene in a.scenes:
            sdir = os.path.join(a.evaldata, scene)
            ref, ref_var = reference(a.proden, sdir, tmp)
            ref_passes = reference_passes(sdir)
            w = 1.0 / (ref * ref + 0.01)
            for level in a.levels:
                passes = sorted(glob.glob(os.path.join(sdir, "spp%d" % level, "pass_*.exr")))
                for den in a.denoisers:
                    for cfg in a.configs:
                        k, nofeat = CONFIGS[cfg]
                        # A new name per cell: OIIO's image cache can serve a file rewritten
                        # within the same second from its old contents.
                        out = os.path.join(tmp, "z_%s_%d_%s_%s.exr" % (scene, level, den, cfg))
                        j = denoise(a.proden, passes[:k], out, den, nofeat)
                        z = read_rgb(out)
                        sq = (z - ref) ** 2 - ref_var
                        true = float(np.mean(sq * w))
                        true_mse = float(np.mean(sq))
                        e = j["estimated_error"]
                        c = {"scene": scene, "level": level, "config": cfg, "passes": k,
                             "spp": j["estimated_error"]["spp"], "denoiser": den,
                             "est": e["relmse"], "low": e["relmse_low"], "high": e["relmse_high"],
                             "true": true, "est_mse": e["mse"], "true_mse": true_mse,
                             "true_se": true_se(z, ref_passes),
                             "calibration": e.get("calibration"),
                             "consistent": e.get("consistent")}
                        c["ratio"] = c["est"] / true if true > 0 else math.inf
                        c["covered"] = (c["low"] is not None and c["low"] <= true and
                                        (c["high"] is None or true <= c["high"]))
                        cells.append(c)
                        print("%-12s %5d %-7s %-3s est %.3g [%s, %s] true %.3g +- %.2g ratio "
                              "%.3f mse ratio %.3f" % (scene, level, den, cfg, c["est"], c["low"],
                                                       c["high"], true, c["true_se"], c["ratio"],
                                                       e["mse"] / true_mse), flush=True)
    write(cells, a.out, a.denoisers, a.configs)


def write(cells, out, denoisers, configs):
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    with open(out + ".json", "w") as f:
        json.dump(cells, f, indent=1)
    write_md(cells, out + ".md", denoisers, configs)


def write_md(cells, path, denoisers, configs):
    lines = []
    for den in denoisers:
        lines.append("**Denoiser `%s`**: est/true relMSE (\\* = outside [0.67, 1.5]; "
                     "(c) = the true value is outside the 95 %% interval; (r) = the verdict "
                     "changes within the truth's own error, +- 2 jackknife standard errors over "
                     "the reference's passes)\n" % den)
        lines.append("| scene | level | " + " | ".join(
            "%s (spp)" % c for c in configs) + " |")
        lines.append("|---|---|" + "---|" * len(configs))
        for scene in sorted({c["scene"] for c in cells}, key=SCENES.index):
            for level in sorted({c["level"] for c in cells}):
                row = []
                for cfg in configs:
                    m = [c for c in cells if (c["scene"], c["level"], c["denoiser"], c["config"])
                         == (scene, level, den, cfg)]
                    if not m:
                        row.append("")
                        continue
                    c = m[0]
                    flag = "" if BAR[0] <= c["ratio"] <= BAR[1] else "\\*"
                    cov = "" if c["covered"] else " (c)"
                    unsure = " (r)" if verdict_unsure(c) else ""
                    row.append("%.2f%s%s%s (%g)" % (c["ratio"], flag, cov, unsure, c["spp"]))
                lines.append("| %s | %d | %s |" % (scene, level, " | ".join(row)))
        lines.append("")
    inbar = [c for c in cells if c["spp"] >= 8]
    bad = [c for c in inbar if not BAR[0] <= c["ratio"] <= BAR[1]]
    low = [c for c in inbar if c["ratio"] < BAR[0]]
    lines.append("Cells from 8 spp: %d; outside [0.67, 1.5]: %d (of which too low, i.e. toward "
                 "\"done\": %d). True value inside the 95 %% interval: %d of %d.\n" % (
                     len(inbar), len(bad), len(low), sum(c["covered"] for c in inbar), len(inbar)))
    if any("true_se" in c for c in inbar):
        sure_bad = [c for c in bad if not verdict_unsure(c)]
        unsure_in = [c for c in inbar if c not in bad and verdict_unsure(c)]
        lines.append("Allowing for the truth's own error (+- 2 jackknife standard errors): outside "
                     "the bar whatever the truth within it: %d (too low: %d); inside the bar but "
                     "not whatever the truth: %d.\n" % (
                         len(sure_bad), sum(c["ratio"] < BAR[0] for c in sure_bad),
                         len(unsure_in)))
    ratios = [c["ratio"] for c in inbar if c["ratio"] > 0 and math.isfinite(c["ratio"])]
    if ratios:
        lines.append("Geometric mean est/true: %.3f; range %.2f..%.2f.\n" % (
            math.exp(sum(map(math.log, ratios)) / len(ratios)), min(ratios), max(ratios)))
    # Per denoiser: cells from 8 spp outside the bar, and each scene's range of est/true.
    scenes = sorted({c["scene"] for c in cells}, key=SCENES.index)
    has_se = any("true_se" in c for c in inbar)
    lines.append("| denoiser | outside [0.67, 1.5] (too low) | " +
                 ("beyond the truth's error (too low) | " if has_se else "") +
                 " | ".join(scenes) + " |")
    lines.append("|---|---|" + ("---|" if has_se else "") + "---|" * len(scenes))
    for den in denoisers:
        mine = [c for c in inbar if c["denoiser"] == den]
        out = [c for c in mine if not BAR[0] <= c["ratio"] <= BAR[1]]
        row = ["%d of %d (%d)" % (len(out), len(mine), sum(c["ratio"] < BAR[0] for c in mine))]
        if has_se:
            sure = [c for c in out if not verdict_unsure(c)]
            row.append("%d (%d)" % (len(sure), sum(c["ratio"] < BAR[0] for c in sure)))
        for scene in scenes:
            r = [c["ratio"] for c in mine if c["scene"] == scene]
            row.append("%.2f-%.2f" % (min(r), max(r)) if r else "")
        lines.append("| `%s` | %s |" % (den, " | ".join(row)))
    lines.append("")
    with open(path, "w") as f:
        f.write("\n".join(lines))


if __name__ == "__main__":
    main()
