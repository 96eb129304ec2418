#!/usr/bin/python3
"""Writes bench/results/nfor.md (included in RESULTS.md by make_results.py) from NFOR's results:
nfor_speed.json (proden_bench_nfor) and nfor_eval_<scene>.jsonl (proden_nfor_eval), plus the
hand-written nfor_optimisation.md (the measured history of the kernels' optimisations).

  bench/nfor_results.py
"""
import glob
import json
import math
import os

HERE = os.path.dirname(os.path.abspath(__file__))
RES = os.path.join(HERE, "results")
SCENE_ORDER = ["cornell", "textured_dof", "glass", "interior"]


def g(v, d=3):
    return "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{d}g}"


def gmean(vals):
    vals = [v for v in vals if v is not None and v > 0 and math.isfinite(v)]
    return math.exp(sum(math.log(v) for v in vals) / len(vals)) if vals else float("nan")


def speed(L):
    p = os.path.join(RES, "nfor_speed.json")
    if not os.path.exists(p):
        return
    s = json.load(open(p))
    L.append(f"### Speed (`proden_bench_nfor`, one run)\n")
    L.append(f"`proden_bench_nfor --threads {s['threads']} --repeat {s['repeat']} --extras` "
             f"(`bench/run_all.sh`): a synthetic {s['width']}x{s['height']} frame with albedo, "
             "normal and depth, 8 passes of 4 spp (both halves); NL-means alone in the pipeline's "
             "256-pixel tiles, then NFOR whole-frame with each kernel build; best wall time of the "
             "repeats. *CPU us/px* is the process's CPU time over the same run and *cores* = "
             "CPU / wall: below the thread count the machine was busy with other jobs, and the wall "
             "time is longer than the code needs. Stage times are wall seconds. Raw: "
             "[results/nfor_speed.txt](results/nfor_speed.txt).\n")
    L.append("| denoiser | wall s | us/px (wall) | / NL-means | CPU us/px | cores | prefilter s |"
             " first pass s | selection s | second pass s |")
    L.append("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in s["rows"]:
        st = r["stages"]
        nf = r["denoiser"].startswith("nfor")
        cores = r["cpu_us_per_pixel"] / r["us_per_pixel"] if r["us_per_pixel"] > 0 else float("nan")
        L.append(f"| {r['denoiser']} | {r['wall_s']:.3f} | {r['us_per_pixel']:.2f} | "
                 f"{r['over_nlmeans']:.2f} | {r['cpu_us_per_pixel']:.2f} | {cores:.2f} | " +
                 (" | ".join(f"{st[k]:.3f}" for k in ("prefilter", "first_pass", "selection",
                                                        "second_pass")) if nf else
                  " | | | ") + " |")
    if s.get("peak_rss_after"):
        L.append(f"\nPeak resident memory of the process: {s['peak_rss_before'] / 1e6:.0f} MB "
                 f"with the frame accumulated and estimated, {s['peak_rss_after'] / 1e6:.0f} MB "
                 f"after the denoisers: NFOR's whole-frame planes add "
                 f"{(s['peak_rss_after'] - s['peak_rss_before']) / 1e6:.0f} MB "
                 f"({(s['peak_rss_after'] - s['peak_rss_before']) / (s['width'] * s['height']):.0f} "
                 "bytes per pixel).")
    L.append("")


def evaluation(L):
    files = {os.path.basename(f)[len("nfor_eval_"):-len(".jsonl")]: f
             for f in glob.glob(os.path.join(RES, "nfor_eval_*.jsonl"))}
    if not files:
        return
    scenes = [s for s in SCENE_ORDER if s in files] + sorted(set(files) - set(SCENE_ORDER))
    rows = {s: [json.loads(l) for l in open(files[s]) if l.strip()] for s in scenes}
    L.append("### Accuracy per scene and level (`proden_nfor_eval`)\n")
    L.append("`proden_nfor_eval --scene $EVALDATA/<scene> --json` on the evaluation sets (256x256, "
             "P = min(8, L) passes, reference 8 x 512 spp). relMSE and SMAPE of the render, NL-means "
             "alone (proden's built-in filter, r=5 f=3), NFOR's first pass after the selection "
             "(§5.3) and NFOR's output (after the second pass when it is on, docs/nfor.md).\n")
    L.append("| scene | spp | relMSE render | NL-means | NFOR selected | NFOR | SMAPE render |"
             " NL-means | NFOR | NFOR / NL-means relMSE |")
    L.append("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    ratio = []
    for s in scenes:
        for r in rows[s]:
            sel = r.get("stages", {}).get("selected", {}).get("relmse")
            q = r["nfor"]["relmse"] / r["nlmeans"]["relmse"]
            ratio.append(q)
            L.append(f"| {s} | {r['spp']:.0f} | {g(r['render']['relmse'])} | "
                     f"{g(r['nlmeans']['relmse'])} | {g(sel)} | {g(r['nfor']['relmse'])} | "
                     f"{g(r['render']['smape'])} | {g(r['nlmeans']['smape'])} | "
                     f"{g(r['nfor']['smape'])} | {q:.2f} |")
    L.append(f"\nGeometric mean of NFOR / NL-means relMSE over {len(ratio)} scene-levels: "
             f"{gmean(ratio):.2f}.\n")

    names = []
    for s in scenes:
        for r in rows[s]:
            for k in r.get("estimates", {}):
                if k not in names:
                    names.append(k)
    label = {"cv": "cross-validation", "hat": "hat diagonal (SURE)", "mc": "Monte-Carlo SURE"}
    L.append("### NFOR's error estimates against the true error\n")
    L.append("Per scene and level: the estimate's mean over the frame / the true mean squared "
             "error of NFOR's output (its squared difference from the reference, minus the "
             "reference's own variance), and how well it ranks 8x8 windows (Spearman rank "
             "correlation of the window means; `cap` = the share of the true error in the 10 % "
             "of windows the estimate ranks worst, relative to the truly worst 10 %). "
             "Candidates: " + "; ".join(f"**{label.get(n, n)}** (`{n}`)" for n in names) +
             " (docs/nfor.md).\n")
    head = "| scene | spp | " + " | ".join(f"{n} est/true | {n} rank 8x8 | {n} cap" for n in names)
    L.append(head + " |")
    L.append("|---|---:|" + "---:|" * (3 * len(names)))
    summary = {n: {"ratio": [], "rank": [], "cap": [], "within2": 0, "count": 0} for n in names}
    for s in scenes:
        for r in rows[s]:
            cells = []
            for n in names:
                e = r.get("estimates", {}).get(n)
                if not e:
                    cells.append("| |")
                    continue
                cells.append(f"{g(e['est_over_true'])} | {e['spearman_8']:.2f} | "
                             f"{e['capture10_8']:.2f}")
                sm = summary[n]
                sm["ratio"].append(e["est_over_true"])
                sm["rank"].append(e["spearman_8"])
                sm["cap"].append(e["capture10_8"])
                sm["count"] += 1
                sm["within2"] += 1 if 0.5 <= e["est_over_true"] <= 2.0 else 0
            L.append(f"| {s} | {r['spp']:.0f} | " + " | ".join(cells) + " |")
    L.append("")
    L.append("| estimate | geometric mean est/true (positive ones) | levels within 0.5..2x | "
             "mean rank correlation 8x8 | mean capture |")
    L.append("|---|---:|---:|---:|---:|")
    for n in names:
        sm = summary[n]
        if not sm["count"]:
            continue
        L.append(f"| {label.get(n, n)} | {gmean(sm['ratio']):.2f} | {sm['within2']} / "
                 f"{sm['count']} | {sum(sm['rank']) / len(sm['rank']):.2f} | "
                 f"{sum(sm['cap']) / len(sm['cap']):.2f} |")
    L.append("")


def main():
    L = ["## NFOR (issue 10; docs/nfor.md)", "",
         "Written by `bench/nfor_results.py` from `bench/results/nfor_*` (`bench/run_all.sh`); "
         "the optimisation history is the hand-written `bench/results/nfor_optimisation.md`.", ""]
    speed(L)
    p = os.path.join(RES, "nfor_optimisation.md")
    if os.path.exists(p):
        L.append(open(p).read().rstrip() + "\n")
    evaluation(L)
    out = os.path.join(RES, "nfor.md")
    with open(out, "w") as f:
        f.write("\n".join(L).rstrip() + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
