#!/usr/bin/python3
"""Sample savings: how many times more samples per pixel plain Monte Carlo needs to reach the same
trimmed relMSE as a denoised frame (issue 10). Writes bench/results/savings.md, a hand-written-style
part that bench/make_results.py includes in RESULTS.md.

    bench/savings.py [--bin build/bench] [--evaldata /work/evaldata] [--scenes a,b] [--reuse]

For every scene it runs `proden_eval_levels --scene DIR --denoiser D --json` for D = nlmeans, nfor
and cascade (or, with --reuse, reads the JSON lines kept from the last run,
bench/results/levels_<D>_<scene>.jsonl) and takes the metrics from there; nothing is re-computed
here. Per scene and level it tabulates, for the render, NL-means alone, NFOR alone, proden (the
progressive mix with the render) on NL-means, on NFOR and on the cascade:

- **savings** = s(e) / L, where L is the level's spp, e the image's trimmed relMSE
  (`relmse_trimmed`: the largest 0.1 % of per-value errors dropped) and s(e) the spp at which the
  render reaches e. s is the render's own curve over the levels, interpolated linearly in
  log(spp)-log(relMSE) after making it non-increasing (running minimum: a render never gets worse
  with more samples, only its firefly noise does). Beyond the curve it is extrapolated at Monte
  Carlo's rate, relMSE ~ 1/spp, from its last point (below the lowest level: from its first
  point). The render's own savings are 1 where its curve is monotone.
- **ratios** of proden's frames to min(render, its denoiser), in trimmed relMSE, relMSE and SMAPE
  (the cascade's denoisers are NL-means and NFOR: min of render, NL-means and NFOR).
- geometric means over the levels per scene and over all scene-levels.
"""
import argparse
import json
import math
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
RES = os.path.join(HERE, "results")
# Runs of proden_eval_levels: tag -> its arguments. "nlmeans-coarse" is the default before issue
# 10's cascade work: NL-means with the authors' t-test alone (no fine-scale second test).
RUNS = {"nlmeans": ["--denoiser", "nlmeans"], "nfor": ["--denoiser", "nfor"],
        "cascade": ["--denoiser", "cascade"],
        "nlmeans-coarse": ["--denoiser", "nlmeans", "--no-ttest-fine"]}
# Rows of the savings table: (label, denoiser run, key in that run's JSON line).
METHODS = (
    ("render", "nlmeans", "render"),
    ("NL-means", "nlmeans", "denoised"),
    ("NFOR", "nfor", "denoised"),
    ("proden NL-means (before)", "nlmeans-coarse", "result"),
    ("proden NL-means", "nlmeans", "result"),
    ("proden NFOR", "nfor", "result"),
    ("proden cascade", "cascade", "result"),
)
PRODEN = {"proden NL-means (before)": ("NL-means",), "proden NL-means": ("NL-means",), "proden NFOR": ("NFOR",),
          "proden cascade": ("NL-means", "NFOR")}


def run_levels(binary, scene_dir, run_args, threads):
    out = subprocess.run([binary, "--scene", scene_dir, *run_args, "--json", "--threads",
                          str(threads)], check=True, capture_output=True, text=True)
    return [json.loads(l) for l in out.stdout.splitlines() if l.strip()]


def load(args, scene):
    rows = {}
    for d, run_args in RUNS.items():
        path = os.path.join(RES, f"levels_{d}_{scene}.jsonl")
        if not args.reuse or not os.path.exists(path):
            lines = run_levels(os.path.join(args.bin, "proden_eval_levels"),
                               os.path.join(args.evaldata, scene), run_args, args.threads)
            with open(path, "w") as f:
                f.write("".join(json.dumps(l) + "\n" for l in lines))
        with open(path) as f:
            rows[d] = {round(r["spp"]): r for r in map(json.loads, f) if r}
    levels = sorted(set.intersection(*(set(r) for r in rows.values())))
    return levels, rows


def render_curve(levels, errors):
    """log spp and log relMSE of the render, made non-increasing."""
    e = np.minimum.accumulate(np.asarray(errors, dtype=float))
    return np.log(np.asarray(levels, dtype=float)), np.log(np.maximum(e, 1e-300))


def equivalent_spp(curve, err):
    """spp at which the render reaches `err` (log-log interpolation, 1/spp beyond the ends)."""
    ls, le = curve
    t = math.log(max(err, 1e-300))
    if t >= le[0]:
        return math.exp(ls[0] + (le[0] - t))
    if t <= le[-1]:
        i = int(np.argmax(le == le[-1]))  # the first level on the final plateau
        return math.exp(ls[i] + (le[i] - t))
    i = int(np.searchsorted(-le, -t))  # first point at or below err
    if le[i] == le[i - 1]:
        return math.exp(ls[i - 1])
    u = (le[i - 1] - t) / (le[i - 1] - le[i])
    return math.exp(ls[i - 1] + u * (ls[i] - ls[i - 1]))


def gmean(v):
    v = [x for x in v if x is not None and x > 0 and math.isfinite(x)]
    return math.exp(sum(map(math.log, v)) / len(v)) if v else float("nan")


def fmt(v, d=2):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    if abs(v) >= 100:
        return f"{v:.0f}"
    return f"{v:.{d}f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bin", default=os.path.join(HERE, "..", "build", "bench"))
    ap.add_argument("--evaldata", default=os.environ.get("EVALDATA", "/work/evaldata"))
    ap.add_argument("--scenes", default="cornell,textured_dof,glass,interior")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reuse", action="store_true",
                    help="read the kept JSON lines; run only the missing ones")
    ap.add_argument("--out", default=os.path.join(RES, "savings.md"))
    args = ap.parse_args()

    data = {}  # scene -> level -> label -> metrics
    for scene in args.scenes.split(","):
        levels, rows = load(args, scene)
        data[scene] = {L: {lab: rows[d][L][key] for lab, d, key in METHODS} for L in levels}

    sav = {}  # (scene, L, label) -> savings
    for scene, lv in data.items():
        levels = sorted(lv)
        curve = render_curve(levels, [lv[L]["render"]["relmse_trimmed"] for L in levels])
        for L in levels:
            for lab, _, _ in METHODS:
                sav[scene, L, lab] = equivalent_spp(curve, lv[L][lab]["relmse_trimmed"]) / L
    labels = [m[0] for m in METHODS]

    def ratio(scene, L, lab, key):
        m = data[scene][L]
        best = min(m[b][key] for b in ("render",) + PRODEN[lab])
        return m[lab][key] / best if best > 0 else float("nan")

    out = ["## Sample savings (issue 10; `bench/savings.py`)", ""]
    out.append(
        "*Sample savings* = how many times more spp plain Monte Carlo needs to reach the same "
        "trimmed relMSE (relMSE without the largest 0.1 % of per-value errors, "
        "`relmse_trimmed` of `proden_eval_levels --json`). The render's trimmed relMSE over the "
        "levels is made non-increasing and interpolated log-log per scene; beyond 1024 spp (and "
        "below 4) it is extrapolated at Monte Carlo's rate, relMSE ~ 1/spp, from the last (first) "
        "level, so a frame better than the 1024-spp render saves `1024 e_render(1024) / e / L`. "
        "Frames: the render; NL-means and NFOR alone (the `denoised` layer); proden on each = "
        "the progressive mix with the render (closed-form mixer, both t-tests; the `result`); "
        "*proden NL-means (before)* = the default before the cascade work, NL-means with the "
        "authors' t-test alone (`--no-ttest-fine`); the cascade = `--denoiser cascade` "
        "(docs/cascade.md). Command: `bench/savings.py --bin "
        "build/bench` (runs `proden_eval_levels --denoiser nlmeans|nfor|cascade --json --threads "
        "2` per scene, keeps the JSON lines as `bench/results/levels_<denoiser>_<scene>.jsonl`; "
        "`--reuse` re-tabulates them).")
    out.append("")
    out.append("### Savings per scene and level (x; >1 = fewer samples than the render needs)")
    out.append("")
    out.append("| scene | spp | " + " | ".join(labels) + " |")
    out.append("|---|---:|" + "---:|" * len(labels))
    for scene, lv in data.items():
        for L in sorted(lv):
            out.append(f"| {scene} | {L} | " +
                       " | ".join(fmt(sav[scene, L, lab]) for lab in labels) + " |")
        out.append(f"| **{scene}** | gmean | " + " | ".join(
            f"**{fmt(gmean([sav[scene, L, lab] for L in lv]))}**" for lab in labels) + " |")
    allg = {lab: gmean([v for (s, L, l), v in sav.items() if l == lab]) for lab in labels}
    out.append("| **all** | gmean | " + " | ".join(f"**{fmt(allg[lab])}**" for lab in labels) +
               " |")
    out.append("")

    out.append("### proden against min(render, its denoiser)")
    out.append("")
    out.append("Each cell: trimmed relMSE / relMSE / SMAPE of proden's frame over the best of the "
               "render and the denoiser(s) it mixes (cascade: the best of render, NL-means and "
               "NFOR). The issue's bar for the default: <= 1.02 in relMSE and SMAPE everywhere.")
    out.append("")
    plabs = list(PRODEN)
    out.append("| scene | spp | " + " | ".join(plabs) + " |")
    out.append("|---|---:|" + "---|" * len(plabs))
    worst = {lab: {"relmse_trimmed": (0, None), "relmse": (0, None), "smape": (0, None)}
             for lab in plabs}
    for scene, lv in data.items():
        for L in sorted(lv):
            cells = []
            for lab in plabs:
                r = [ratio(scene, L, lab, k) for k in ("relmse_trimmed", "relmse", "smape")]
                for k, v in zip(("relmse_trimmed", "relmse", "smape"), r):
                    if v > worst[lab][k][0]:
                        worst[lab][k] = (v, f"{scene} {L}")
                cells.append(" / ".join(fmt(v) for v in r))
            out.append(f"| {scene} | {L} | " + " | ".join(cells) + " |")
    out.append("")
    out.append("| | " + " | ".join(plabs) + " |")
    out.append("|---|" + "---|" * len(plabs))
    for k, name in (("relmse_trimmed", "worst trimmed relMSE ratio"),
                    ("relmse", "worst relMSE ratio"), ("smape", "worst SMAPE ratio")):
        out.append(f"| {name} | " + " | ".join(
            f"{fmt(worst[l][k][0])} ({worst[l][k][1]})" for l in plabs) + " |")
    nf = allg["NFOR"]
    out.append("| gmean savings / NFOR alone | " +
               " | ".join(fmt(allg[l] / nf) for l in plabs) + " |")
    for base in ("proden NL-means (before)", "proden NL-means"):
        out.append(f"| gmean savings / {base} | " +
                   " | ".join(fmt(allg[l] / allg[base]) for l in plabs) + " |")
    out.append("")
    # The last criterion: glass at NFOR's worst level (lowest savings) against the render.
    if "glass" in data:
        lv = data["glass"]
        worst_l = min(lv, key=lambda L: sav["glass", L, "NFOR"])
        m = lv[worst_l]
        cells = "; ".join(
            f"{lab} " + " / ".join(fmt(m[lab][k] / m["render"][k]) for k in
                                   ("relmse_trimmed", "relmse", "smape"))
            for lab in ("NFOR", "NL-means", "proden NL-means (before)", "proden NFOR",
                        "proden cascade"))
        out.append(f"Glass at NFOR's worst level ({worst_l} spp, savings "
                   f"{fmt(sav['glass', worst_l, 'NFOR'])}), over the render in trimmed relMSE / "
                   f"relMSE / SMAPE: {cells}.")
        out.append("")
    out.append("Reading glass: its render's *trimmed* relMSE rises from 64 spp on (0.045 at 64, "
               "0.2 at 512): with more samples, more than 0.1 % of the values are fireflies, "
               "which trimming no longer removes, while a denoiser spreads each firefly over "
               "many pixels that trimming never removes. So on glass every frame's savings fall "
               "below 1 at high spp, and the untrimmed relMSE and SMAPE columns above tell more.")
    out.append("")
    with open(args.out, "w") as f:
        f.write("\n".join(out) + "\n")
    summary = {"gmean_savings": allg,
               "worst": {l: {k: list(v) for k, v in w.items()} for l, w in worst.items()}}
    with open(os.path.join(RES, "savings.json"), "w") as f:
        json.dump(summary, f, indent=1)
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
