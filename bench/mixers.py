#!/usr/bin/python3
"""Both mixers on one denoiser's output (issue 10: "both mixers must work on NFOR's output; retrain
the network on NFOR inputs if that wins, and report either way"). Writes
bench/results/mixers_<denoiser>.md, which bench/make_results.py includes in RESULTS.md.

    bench/mixers.py --denoiser nfor|cascade|nlmeans [--bin build/bench] \\
        [--evaldata /work/evaldata] [--weights LABEL=FILE.pdnw ...] [--reuse]

Per scene it runs `proden_eval_levels --denoiser D --json` with the closed-form mixer and with
the network (the built-in weights, and each --weights file), all in one run of one binary, keeps
the JSON lines as bench/results/levels_<D>_mixer_<label>_<scene>.jsonl (--reuse reads them
instead), and tabulates proden's result per mixer: sample savings (bench/savings.py's definition:
trimmed relMSE against the render's own curve) and the network's relMSE and SMAPE over the
closed form's.
"""
import argparse
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from savings import RES, equivalent_spp, fmt, gmean, render_curve, run_levels  # noqa: E402

SCENES = ["cornell", "textured_dof", "glass", "interior"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bin", default=os.path.join(HERE, "..", "build", "bench"))
    ap.add_argument("--evaldata", default=os.environ.get("EVALDATA", "/work/evaldata"))
    ap.add_argument("--weights", nargs="*", default=[], metavar="LABEL=FILE")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reuse", action="store_true")
    ap.add_argument("--denoiser", default="nfor", choices=["nlmeans", "nfor", "cascade"])
    ap.add_argument("--out", help="default bench/results/mixers_<denoiser>.md")
    a = ap.parse_args()
    a.out = a.out or os.path.join(RES, "mixers_%s.md" % a.denoiser)
    runs = {"closed-form": ["--mixer", "closed-form"], "network": ["--mixer", "network"]}
    for w in a.weights:
        label, path = w.split("=", 1)
        runs[label] = ["--mixer", "network", "--weights", path]
    data = {}  # scene -> label -> spp -> line
    scenes = a.scenes.split(",")
    for scene in scenes:
        for label, args in runs.items():
            path = os.path.join(RES, "levels_%s_mixer_%s_%s.jsonl" % (a.denoiser, label, scene))
            if not (a.reuse and os.path.exists(path)):
                lines = run_levels(os.path.join(a.bin, "proden_eval_levels"),
                                   os.path.join(a.evaldata, scene),
                                   ["--denoiser", a.denoiser, *args], a.threads)
                with open(path, "w") as f:
                    f.write("".join(json.dumps(l) + "\n" for l in lines))
            with open(path) as f:
                data.setdefault(scene, {})[label] = {
                    round(r["spp"]): r for r in map(json.loads, f) if r}
    labels = list(runs)
    others = [l for l in labels if l != "closed-form"]
    name = {"nlmeans": "NL-means", "nfor": "NFOR", "cascade": "the cascade"}[a.denoiser]
    L = ["### Both mixers on %s (issue 10; `bench/mixers.py --denoiser %s`)\n" % (name, a.denoiser),
         "proden on %s with each mixer (t-tests on), one run of one binary "
         "(`proden_eval_levels --denoiser %s --mixer M`). *Savings* as in *Sample savings* "
         "(trimmed relMSE against the render's own curve); *rel* and *SMAPE*: the network's "
         "relMSE and SMAPE over the closed form's (< 1: the network is better). Mixers: "
         % (name, a.denoiser) +
         ", ".join("`%s` (%s)" % (l, " ".join(runs[l])) for l in labels) + ".\n",
         "| scene | spp | %s alone | " % name + " | ".join("%s savings" % l for l in labels) + " | " +
         " | ".join("%s rel / SMAPE" % l for l in others) + " |",
         "|---|---:|---:|" + "---:|" * len(labels) + "---|" * len(others)]
    sav = {l: [] for l in labels + ["alone"]}
    for scene in scenes:
        d = data[scene]
        levels = sorted(set.intersection(*(set(d[l]) for l in labels)))
        cf = d["closed-form"]
        curve = render_curve(levels, [cf[v]["render"]["relmse_trimmed"] for v in levels])
        per = {l: [] for l in labels + ["alone"]}
        for v in levels:
            s = {l: equivalent_spp(curve, d[l][v]["result"]["relmse_trimmed"]) / v for l in labels}
            s["alone"] = equivalent_spp(curve, cf[v]["denoised"]["relmse_trimmed"]) / v
            for l in s:
                per[l].append(s[l])
                sav[l].append(s[l])
            cells = ["%s / %s" % (fmt(d[l][v]["result"]["relmse"] / cf[v]["result"]["relmse"]),
                                  fmt(d[l][v]["result"]["smape"] / cf[v]["result"]["smape"]))
                     for l in others]
            L.append("| %s | %d | %s | %s | %s |" % (scene, v, fmt(s["alone"]),
                                                    " | ".join(fmt(s[l]) for l in labels),
                                                    " | ".join(cells)))
        L.append("| **%s** | gmean | **%s** | %s | |" % (
            scene, fmt(gmean(per["alone"])),
            " | ".join("**%s**" % fmt(gmean(per[l])) for l in labels) +
            " |" * (len(others) - 1)))
    L.append("| **all** | gmean | **%s** | %s | |\n" % (
        fmt(gmean(sav["alone"])),
        " | ".join("**%s**" % fmt(gmean(sav[l])) for l in labels) + " |" * (len(others) - 1)))
    # The bar: <= 1.02x min(render, the denoiser alone) in relMSE and SMAPE.
    L.append("Against the bar (<= 1.02x min(render, %s alone) in relMSE and SMAPE), per mixer: "
             "cells over 1.02 of %d, and the worst.\n" % (name, sum(
                 len(set.intersection(*(set(data[sc][l]) for l in labels))) for sc in scenes)))
    L.append("| mixer | relMSE > 1.02 | worst relMSE | SMAPE > 1.02 | worst SMAPE |")
    L.append("|---|---:|---|---:|---|")
    for l in labels:
        worst = {}
        for key in ("relmse", "smape"):
            r = []
            for sc in scenes:
                for v, line in data[sc][l].items():
                    best = min(line["render"][key], line["denoised"][key])
                    r.append((line["result"][key] / best if best > 0 else float("inf"), sc, v))
            worst[key] = (sum(x[0] > 1.02 for x in r), max(r))
        L.append("| %s | %d | %s (%s %d) | %d | %s (%s %d) |" % (
            l, worst["relmse"][0], fmt(worst["relmse"][1][0]), *worst["relmse"][1][1:],
            worst["smape"][0], fmt(worst["smape"][1][0]), *worst["smape"][1][1:]))
    L.append("")
    if "glass" in scenes and all(32 in data["glass"][l] for l in labels):
        # The glass bar: at NFOR's worst level (32 spp) no worse than the render.
        L.append("Glass at NFOR's worst level (32 spp), proden's result over the render in trimmed "
                 "relMSE / relMSE / SMAPE: " + "; ".join(
                     "%s %s" % (l, " / ".join(
                         fmt(data["glass"][l][32]["result"][k] / data["glass"][l][32]["render"][k])
                         for k in ("relmse_trimmed", "relmse", "smape"))) for l in labels) + ".\n")
    with open(a.out, "w") as f:
        f.write("\n".join(L) + "\n")
    print("\n".join(L))


if __name__ == "__main__":
    main()
