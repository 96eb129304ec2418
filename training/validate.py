#!/usr/bin/python3
"""Validation table of the mixers as proden runs them (C++, after the t-test).

For every validation frame (TRAINING_DATA/val/<frame>/, scenes never trained on) and spp level,
runs `proden denoise --aov` once with the closed-form mixer and once with the network, and
measures RMSE, relMSE (i-r)^2/(r^2+0.01) and SMAPE |i-r|/(|i|+|r|+0.01) of the render, the
denoised image and both results against the frame's 1024-spp reference (frame.npz `ref`).

    /usr/bin/python3 training/validate.py [--weights FILE] [--proden BIN] [--json OUT]
                                          [--no-ttest] [--markdown OUT.md]
                                          [--evaldata DIR --eval-levels BIN]

Prints a per-level table (mean over frames) and the paper-style average over all frames and
levels; `--json` keeps every row. With --evaldata, also the benchmark scenes (bench/
render_eval_set.sh: cornell, textured_dof, glass, interior at 256x256, 4..1024 spp, 8 passes per
level) through proden_eval_levels with each mixer: relMSE of the result per scene and level.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from render_set import LEVELS, level_files, read_exr, rgb  # noqa: E402

IMAGES = ["render", "denoised", "closed-form", "network"]


def metrics(img, ref):
    d = img.astype(np.float64) - ref
    return {
        "rmse": float(np.sqrt(np.mean(d * d))),
        "relmse": float(np.mean(d * d / (ref * ref + 0.01))),
        "smape": float(np.mean(np.abs(d) / (np.abs(img) + np.abs(ref) + 0.01))),
    }


def run(proden, files, out, mixer, weights, ttest):
    cmd = [proden, "denoise", "--aov", "--json", "-q", "--timings", "--mixer", mixer, "--out", out]
    if weights and mixer == "network":
        cmd += ["--weights", weights]
    if not ttest:
        cmd.append("--no-ttest")
    res = subprocess.run(cmd + files, check=True, capture_output=True, text=True)
    summary = json.loads(res.stdout)
    names, px = read_exr(out)
    return summary, {k: rgb(names, px, p, out) for k, p in
                     (("result", ""), ("render", "render."), ("denoised", "denoised."))}


def evaldata_table(bin_path, root, weights):
    """relMSE / SMAPE of the result with each mixer on the benchmark scenes (t-test on)."""
    rows = {}
    for scene in sorted(os.listdir(root)):
        sdir = os.path.join(root, scene)
        if not os.path.isdir(os.path.join(sdir, "reference")):
            continue
        for mixer in ("closed-form", "network"):
            cmd = [bin_path, "--scene", sdir, "--json", "--mixer", mixer]
            if weights and mixer == "network":
                cmd += ["--weights", weights]
            out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
            for line in out.splitlines():
                r = json.loads(line)
                row = rows.setdefault((scene, int(r["spp"])), {})
                row[mixer] = r["result"]
                row["render"], row["denoised"] = r["render"], r["denoised"]
    lines = ["| scene | spp | render relMSE | denoised | closed-form | network | network / "
             "closed-form |", "|---|---:|---:|---:|---:|---:|---:|"]
    ratios = []
    for (scene, spp), r in sorted(rows.items()):
        q = r["network"]["relmse"] / max(r["closed-form"]["relmse"], 1e-12)
        ratios.append(q)
        lines.append("| %s | %d | %.5f | %.5f | %.5f | %.5f | %.3f |" % (
            scene, spp, r["render"]["relmse"], r["denoised"]["relmse"],
            r["closed-form"]["relmse"], r["network"]["relmse"], q))
    lines.append("\nGeometric mean of network / closed-form relMSE over %d scene-levels: %.3f "
                 "(< 1: the network is better); better in %d of them.\n" % (
                     len(ratios), float(np.exp(np.mean(np.log(ratios)))),
                     sum(q < 1 for q in ratios)))
    return "\n".join(lines), rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=os.environ.get("TRAINING_DATA", "/work/trainingdata"))
    ap.add_argument("--proden", default=os.environ.get(
        "PRODEN", os.path.join(os.path.dirname(HERE), "build", "proden")))
    ap.add_argument("--weights", default="", help="network weights (default: built-in)")
    ap.add_argument("--no-ttest", action="store_true")
    ap.add_argument("--json", default="")
    ap.add_argument("--markdown", default="")
    ap.add_argument("--evaldata", default="", help="benchmark scenes root (e.g. /work/evaldata)")
    ap.add_argument("--eval-levels", default=os.path.join(os.path.dirname(HERE), "build", "bench",
                                                           "proden_eval_levels"))
    a = ap.parse_args()

    val = os.path.join(a.data, "val")
    frames = sorted(f for f in os.listdir(val) if os.path.isfile(os.path.join(val, f, "frame.npz")))
    if not frames:
        sys.exit("no validation frames in %s" % val)
    rows = []
    t0 = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        for fr in frames:
            fdir = os.path.join(val, fr)
            ref = np.load(os.path.join(fdir, "frame.npz"))["ref"].astype(np.float64)
            for lv in LEVELS:
                files = level_files(fdir, lv)
                if not all(os.path.isfile(f) for f in files):
                    continue
                row = {"frame": fr, "spp": lv}
                for mixer in ("closed-form", "network"):
                    out = os.path.join(tmp, "%s_%d_%s.exr" % (fr, lv, mixer))
                    summ, img = run(a.proden, files, out, mixer, a.weights, not a.no_ttest)
                    if mixer == "closed-form":
                        row["render"] = metrics(img["render"], ref)
                        row["denoised"] = metrics(img["denoised"], ref)
                    row[mixer] = metrics(img["result"], ref)
                    row[mixer + "_mixer_cpu_s"] = summ["timings"]["mixer_cpu"]
                    row[mixer + "_name"] = summ["pipeline"]["mixer"]
                rows.append(row)
    wall = time.time() - t0

    lines = []
    head = "| spp | " + " | ".join("%s RMSE / relMSE / SMAPE" % k for k in IMAGES) + " |"
    lines += [head, "|" + "---|" * (len(IMAGES) + 1)]

    def cell(sel, k):
        return " / ".join("%.4f" % np.mean([r[k][m] for r in sel])
                          for m in ("rmse", "relmse", "smape"))

    for lv in LEVELS:
        sel = [r for r in rows if r["spp"] == lv]
        if sel:
            lines.append("| %d | " % lv + " | ".join(cell(sel, k) for k in IMAGES) + " |")
    lines.append("| **mean** | " + " | ".join(cell(rows, k) for k in IMAGES) + " |")
    wins = {m: sum(r["network"][m] < r["closed-form"][m] for r in rows)
            for m in ("rmse", "relmse", "smape")}
    mixer_cpu = {k: float(np.mean([r[k + "_mixer_cpu_s"] for r in rows]))
                 for k in ("closed-form", "network")}
    text = "\n".join(lines)
    text += ("\n\n%d frames x levels (%d validation frames), t-test %s; network better than "
             "closed-form in %d/%d (RMSE), %d/%d (relMSE), %d/%d (SMAPE) of them; mean mixer CPU "
             "s per 128x128 frame: closed-form %.4f, network %.4f (%s); %.0f s.\n" % (
                 len(rows), len(frames), "off" if a.no_ttest else "on", wins["rmse"], len(rows),
                 wins["relmse"], len(rows), wins["smape"], len(rows), mixer_cpu["closed-form"],
                 mixer_cpu["network"], rows[0]["network_name"], wall))
    if a.evaldata:
        table, _ = evaldata_table(a.eval_levels, a.evaldata, a.weights)
        text += "\nBenchmark scenes (%s, 256x256, t-test on), relMSE of the result:\n\n%s" % (
            a.evaldata, table)
    print(text)
    if a.markdown:
        with open(a.markdown, "w") as f:
            f.write(text)
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"rows": rows, "weights": a.weights or "built-in",
                       "t_test": not a.no_ttest}, f, indent=1)


if __name__ == "__main__":
    main()
