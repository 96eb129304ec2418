#!/usr/bin/python3
"""Accuracy versus time: what proden's post-process buys against spending the time on samples.

For each scene set (bench/render_eval_set.sh layout: DIR/spp<L>/pass_*.exr, DIR/reference/,
DIR/timings.tsv) runs `proden_eval_levels --json`, joins Blender's render time per level and
writes, into the output directory (default bench/results/):

  accuracy_<scene>.jsonl  the raw eval_levels rows (so plots/summaries can be redone offline)
  accuracy_<scene>.csv    one row per level: spp, seconds of each curve, errors, estimates
  accuracy_<scene>.png    log-log error vs seconds: render-only, denoise-only, proden
  accuracy.md             the tables and the summary that bench/RESULTS.md includes
  accuracy_summary.json   headline numbers for bench/make_results.py

Time axis (seconds, one frame at 256x256 on this machine):
  render-only   L spp x the scene's Blender render seconds per spp (median over the set's
                passes of `cycles.ViewLayer.render_time` / spp, timings.tsv): path tracing
                only, without Blender's start-up, scene sync and BVH build, which a farm pays
                per pass as well. `--time-model measured` uses the level's own summed headers
                (kept in the CSV as render_s_measured; noisy on a shared machine)
  denoise-only  render-only + proden's read/accumulate + the NL-means filter alone
  proden        render-only + one proden update (read/accumulate + full pipeline): a progressive
                farm reaches L spp and then publishes once; earlier updates overlap rendering
Errors are against the reference (8 passes x 512 spp); `mse_corrected` subtracts the
reference's own variance. relMSE = (i-r)^2/(r^2+0.01), SMAPE = |i-r|/(|i|+|r|+0.01).

  bench/accuracy.py [--bin DIR] [--evaldata DIR] [--out DIR] [--scenes a,b] [--reuse]
  bench/accuracy.py --self-test     # plots and summarises a synthetic set into a temp dir
"""
import argparse
import csv
import json
import math
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SCENES = ["cornell", "textured_dof", "glass", "interior"]
DESCR = {
    "cornell": "Cornell box, small ceiling light (mostly indirect, glossy block, metal sphere)",
    "textured_dof": "fine textures + f/0.9 depth of field, sky + sun",
    "glass": "glass objects, caustics on, no clamp (fireflies)",
    "interior": "closed room lit only indirectly (hidden light)",
}
CURVES = [("render", "render-only", "#444444", "o"),
          ("denoised", "denoise-only (NL-means)", "#1f77b4", "s"),
          ("result", "proden (progressive)", "#d62728", "^")]


def to_seconds(s):
    t = 0.0
    for part in s.strip().split(":"):
        t = t * 60 + float(part)
    return t


def render_times(scene_dir):
    """file (relative) -> Blender render seconds; the last timings.tsv line of a file counts."""
    out = {}
    tsv = os.path.join(scene_dir, "timings.tsv")
    if os.path.exists(tsv):
        with open(tsv) as f:
            for row in csv.DictReader(f, delimiter="\t"):
                try:
                    out[row["file"]] = float(row["render_s"])
                except (KeyError, ValueError):
                    pass
    return out


def header_render_time(path):
    try:
        txt = subprocess.run(["oiiotool", "--info", "-v", path], capture_output=True, text=True,
                             check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    for line in txt.splitlines():
        line = line.strip()
        if line.startswith("cycles.ViewLayer.render_time:"):
            return to_seconds(line.split(":", 1)[1].strip().strip('"'))
    return None


def level_render_seconds(scene_dir, level, times):
    d = os.path.join(scene_dir, f"spp{level}")
    total, n = 0.0, 0
    for name in sorted(os.listdir(d)):
        if not (name.startswith("pass_") and name.endswith(".exr")):
            continue
        rel = f"spp{level}/{name}"
        t = times.get(rel)
        if t is None:
            t = header_render_time(os.path.join(d, name))
        if t is None:
            raise SystemExit(f"no render time for {rel} (timings.tsv or EXR header)")
        total += t
        n += 1
    return total, n


def run_eval(binary, scene_dir, threads):
    cmd = [binary, "--scene", scene_dir, "--json"]
    if threads:
        cmd += ["--threads", str(threads)]
    print("+", " ".join(cmd), file=sys.stderr, flush=True)
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    return [json.loads(l) for l in out.splitlines() if l.strip()]


def seconds_per_spp(scene_dir):
    """Blender render seconds per spp of the scene (256x256): the median over the set's passes of
    >= 8 spp (their render_time is long enough for the header's 0.01 s resolution). The median
    of ~100 passes resists the contention of a shared machine that single levels suffer."""
    tsv = os.path.join(scene_dir, "timings.tsv")
    rates = []
    if os.path.exists(tsv):
        with open(tsv) as f:
            for row in csv.DictReader(f, delimiter="\t"):
                try:
                    spp, rs = float(row["spp"]), float(row["render_s"])
                except (KeyError, ValueError):
                    continue
                if spp >= 8 and rs > 0:
                    rates.append(rs / spp)
    if not rates:
        return None
    rates.sort()
    n = len(rates)
    return rates[n // 2] if n % 2 else 0.5 * (rates[n // 2 - 1] + rates[n // 2])


def rows_for_scene(scene, scene_dir, evals, time_model="median"):
    times = render_times(scene_dir)
    rate = seconds_per_spp(scene_dir) if time_model == "median" else None
    rows = []
    for e in sorted(evals, key=lambda r: r["spp"]):
        level = int(round(e["spp"]))
        rs, npass = level_render_seconds(scene_dir, level, times)
        sec = e["seconds"]
        r = {"scene": scene, "spp": level, "passes": e["passes"], "render_s_measured": rs,
             "render_s": level * rate if rate else rs,
             "read_accumulate_s": sec["read_accumulate"], "pipeline_s": sec["pipeline_wall"],
             "denoise_only_s": sec["denoise_only_wall"]}
        t = r["render_s"]
        r["t_render"] = t
        r["t_denoised"] = t + sec["read_accumulate"] + sec["denoise_only_wall"]
        r["t_result"] = t + sec["read_accumulate"] + sec["pipeline_wall"]
        for k in ("render", "denoised", "result"):
            for m in ("rmse", "relmse", "smape", "mse", "mse_corrected"):
                r[f"{k}_{m}"] = e[k][m]
            r[f"est_{k}_mse"] = e[f"estimated_mse_{k}"]
            tm = e[k]["mse_corrected"]
            r[f"est_over_true_{k}"] = r[f"est_{k}_mse"] / tm if tm > 0 else float("nan")
        rows.append(r)
    return rows


CSV_FIELDS = ["scene", "spp", "passes", "render_s", "render_s_measured", "read_accumulate_s", "pipeline_s",
              "denoise_only_s", "t_render", "t_denoised", "t_result"] + [
    f"{k}_{m}" for k in ("render", "denoised", "result")
    for m in ("rmse", "relmse", "smape", "mse", "mse_corrected")] + [
    f"est_{k}_mse" for k in ("render", "denoised", "result")] + [
    f"est_over_true_{k}" for k in ("render", "denoised", "result")]


def write_csv(path, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_FIELDS)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{r[k]:.6g}" if isinstance(r[k], float) else r[k])
                        for k in CSV_FIELDS})


def read_csv(path):
    rows = []
    with open(path) as f:
        for r in csv.DictReader(f):
            rows.append({k: (v if k == "scene" else (int(v) if k in ("spp", "passes")
                                                    else float(v))) for k, v in r.items()})
    return rows


# --- log-log interpolation of the render-only curve ------------------------------------------

def loglog_interp(xs, ys, x, slope_lo, slope_hi):
    """y at x on the piecewise power law through (xs, ys) (sorted by x); outside the range the
    end points are extended with the given log-log slopes (render MSE ~ 1/t: slope -1)."""
    lx = [math.log(v) for v in xs]
    ly = [math.log(max(v, 1e-30)) for v in ys]
    l = math.log(x)
    if l <= lx[0]:
        return math.exp(ly[0] + slope_lo * (l - lx[0])), "extrapolated"
    if l >= lx[-1]:
        return math.exp(ly[-1] + slope_hi * (l - lx[-1])), "extrapolated"
    for i in range(len(lx) - 1):
        if lx[i] <= l <= lx[i + 1]:
            f = (l - lx[i]) / (lx[i + 1] - lx[i]) if lx[i + 1] > lx[i] else 0.0
            return math.exp(ly[i] + f * (ly[i + 1] - ly[i])), "interpolated"
    return math.exp(ly[-1]), "interpolated"


def monotone_render(rows, metric):
    """Render-only points sorted by time, as a non-increasing envelope (measured times are noisy
    on a shared machine; a later level with a shorter summed time is dropped from the curve)."""
    pts = sorted((r["t_render"], r[f"render_{metric}"], r["spp"]) for r in rows)
    return pts


def summarise(rows, metric="relmse"):
    """Equal-time win of proden over render-only (and over denoise-only) per level."""
    slope = -0.5 if metric in ("rmse", "smape") else -1.0
    pts = monotone_render(rows, metric)
    xs = [p[0] for p in pts]
    ys = [p[1] for p in pts]
    # spp axis too: render error vs spp (exact, no timing noise).
    sp = sorted((r["spp"], r[f"render_{metric}"]) for r in rows)
    out = []
    for r in rows:
        e_render_eq, how = loglog_interp(xs, ys, r["t_result"], slope, slope)
        e_p = r[f"result_{metric}"]
        # spp the render alone needs to reach proden's error (power law in spp)
        spp_eq = None
        lsx = [math.log(s) for s, _ in sp]
        lsy = [math.log(max(e, 1e-30)) for _, e in sp]
        le = math.log(max(e_p, 1e-30))
        if le >= lsy[0]:
            spp_eq = math.exp(lsx[0] + (le - lsy[0]) / slope)
        elif le <= lsy[-1]:
            spp_eq = math.exp(lsx[-1] + (le - lsy[-1]) / slope)
        else:
            for i in range(len(lsx) - 1):
                a, b = lsy[i], lsy[i + 1]
                if min(a, b) <= le <= max(a, b) and a != b:
                    spp_eq = math.exp(lsx[i] + (le - a) / (b - a) * (lsx[i + 1] - lsx[i]))
                    break
            if spp_eq is None:
                spp_eq = float("nan")
        out.append({"spp": r["spp"], "t_result": r["t_result"], "t_render": r["t_render"],
                    "e_result": e_p, "e_render_same_time": e_render_eq, "how": how,
                    "win": e_render_eq / e_p if e_p > 0 else float("inf"),
                    "win_vs_denoised": r[f"denoised_{metric}"] / e_p if e_p > 0 else float("inf"),
                    "render_spp_equivalent": spp_eq})
    # Where proden stops paying off: the first level from which on it loses at every higher
    # level (None if it still wins at the highest level).
    crossover = None
    for s in reversed(out):
        if s["win"] < 1.0:
            crossover = s
        else:
            break
    return out, crossover


def wins_text(summ, metric):
    won = [s["spp"] for s in summ if s["win"] >= 1.0]
    lost = [s["spp"] for s in summ if s["win"] < 1.0]
    if not lost:
        return f"by {metric} proden wins at every measured level"
    if not won:
        return f"by {metric} proden never pays off (loses at every level)"
    return (f"by {metric} proden wins at {', '.join(map(str, won))} spp and loses at "
            f"{', '.join(map(str, lost))} spp")


# --- plotting ---------------------------------------------------------------------------------

def plot(scene, rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    for ax, metric, label in ((axes[0], "relmse", "relMSE"), (axes[1], "rmse", "RMSE")):
        for key, name, colour, marker in CURVES:
            xs = [r[f"t_{key}"] for r in rows]
            ys = [r[f"{key}_{metric}"] for r in rows]
            ax.loglog(xs, ys, marker=marker, color=colour, label=name, lw=1.6, ms=5)
        # spp labels on the proden curve
        for r in rows:
            ax.annotate(f"{r['spp']}", (r["t_result"], r[f"result_{metric}"]),
                        textcoords="offset points", xytext=(4, 5), fontsize=7, color="#d62728")
        # ideal render-only slope from the highest level (MSE ~ 1/t)
        last = max(rows, key=lambda r: r["spp"])
        s = -1.0 if metric == "relmse" else -0.5
        t0 = min(r["t_render"] for r in rows)
        t1 = max(max(r["t_result"] for r in rows), last["t_render"]) * 1.5
        ax.loglog([t0, t1], [last[f"render_{metric}"] * (t / last["t_render"]) ** s
                             for t in (t0, t1)], ":", color="#999999", lw=1,
                  label="render ideal (MSE ~ 1/t)")
        ax.set_xlabel("seconds (Blender render time + proden, 256x256, 2 cores)")
        ax.set_ylabel(label + " vs 4096-spp reference")
        ax.grid(True, which="both", alpha=0.25)
        ax.set_title(f"{label}")
    axes[0].legend(fontsize=8, loc="lower left")
    fig.suptitle(f"{scene}: {DESCR.get(scene, '')}  (labels: spp)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


# --- report -----------------------------------------------------------------------------------

def fmt(v, d=3):
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "n/a"
    if isinstance(v, float):
        if v != 0 and (abs(v) < 1e-3 or abs(v) >= 1e4):
            return f"{v:.{d - 1}e}"
        return f"{v:.{d}g}" if abs(v) < 1 else f"{v:.{d}g}"
    return str(v)


def scene_section(scene, rows):
    L = []
    summ, cross = summarise(rows, "relmse")
    summ_r, cross_r = summarise(rows, "rmse")
    L.append(f"### {scene}: {DESCR.get(scene, '')}\n")
    L.append(f"![{scene}](results/accuracy_{scene}.png)\n")
    L.append("| spp | render s | proden s | relMSE render | denoised | proden | "
             "RMSE render | proden | SMAPE render | proden | win relMSE (equal time) | "
             "win RMSE | render spp for proden's relMSE |")
    L.append("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r, s, sr in zip(rows, summ, summ_r):
        L.append(f"| {r['spp']} | {r['t_render']:.2f} | {r['t_result']:.2f} | "
                 f"{fmt(r['render_relmse'])} | {fmt(r['denoised_relmse'])} | "
                 f"{fmt(r['result_relmse'])} | {fmt(r['render_rmse'])} | {fmt(r['result_rmse'])} | "
                 f"{fmt(r['render_smape'])} | {fmt(r['result_smape'])} | "
                 f"{s['win']:.2f}x{'*' if s['how'] == 'extrapolated' else ''} | "
                 f"{sr['win']:.2f}x{'*' if sr['how'] == 'extrapolated' else ''} | "
                 f"{s['render_spp_equivalent']:.0f} |")
    L.append("")
    for name, sm, cr in (("relMSE", summ, cross), ("RMSE", summ_r, cross_r)):
        txt = wins_text(sm, name)
        if cr and any(x["win"] >= 1.0 for x in sm):
            txt += (f"; it stops paying off at **{cr['spp']} spp, {cr['t_result']:.1f} s** "
                    f"(win {cr['win']:.2f}x)")
        elif not cr:
            txt += f"; at the highest level, {sm[-1]['spp']} spp, it wins {sm[-1]['win']:.2f}x"
        L.append(f"- {txt}.")
    L.append("\n")
    return L, summ, cross, summ_r, cross_r


def agreement_table(all_rows):
    L = ["| scene | spp | est/true MSE render | est/true MSE denoised | est/true MSE proden |",
         "|---|---:|---:|---:|---:|"]
    for scene, rows in all_rows.items():
        for r in rows:
            L.append(f"| {scene} | {r['spp']} | {fmt(r['est_over_true_render'])} | "
                     f"{fmt(r['est_over_true_denoised'])} | {fmt(r['est_over_true_result'])} |")
    return L


def geo_mean(v):
    v = [x for x in v if x > 0 and not math.isnan(x) and not math.isinf(x)]
    return math.exp(sum(math.log(x) for x in v) / len(v)) if v else float("nan")


def report(all_rows, out_dir):
    L = ["## Accuracy versus time (`bench/accuracy.py`)\n",
         "Scenes at 256x256 from `bench/render_eval_set.sh` (levels: P = min(8, L) passes of L/P "
         "spp; reference 8 x 512 spp, its own variance subtracted from the MSE). "
         "Seconds: **render-only** = L x the scene's Blender render seconds per spp (median over the "
         "set's passes of `cycles.ViewLayer.render_time` / spp; the level's own measured sum is "
         "in the CSV as `render_s_measured` but is too noisy on the shared 2-core machine) "
         "(path tracing only: Blender's start-up, sync and BVH build are "
         "excluded, so the comparison is as favourable to rendering as it gets); "
         "**denoise-only** adds proden's read+accumulate and the NL-means filter alone; "
         "**proden** adds one full update (read+accumulate+pipeline), i.e. the time a "
         "progressive farm needs to reach L spp and publish once. *Win* = render-only error "
         "at the same seconds (log-log interpolation of the render curve; `*` = extrapolated "
         "with MSE ~ 1/t beyond the measured range) / proden's error; >1 means proden's frame "
         "is better for the same wall time. The last column: spp the render alone needs to "
         "reach proden's relMSE (power law through the render points).\n"]
    headline = {"scenes": {}}
    for scene, rows in all_rows.items():
        sec, summ, cross, summ_r, cross_r = scene_section(scene, rows)
        L += sec
        first = summ[0]
        headline["scenes"][scene] = {
            "levels": [r["spp"] for r in rows],
            "win_relmse": {str(s["spp"]): s["win"] for s in summ},
            "win_rmse": {str(s["spp"]): s["win"] for s in summ_r},
            "win_vs_denoised_relmse": {str(s["spp"]): s["win_vs_denoised"] for s in summ},
            "render_spp_equivalent": {str(s["spp"]): s["render_spp_equivalent"] for s in summ},
            "crossover_relmse": None if not cross else {"spp": cross["spp"],
                                                        "seconds": cross["t_result"]},
            "crossover_rmse": None if not cross_r else {"spp": cross_r["spp"],
                                                        "seconds": cross_r["t_result"]},
            "lowest_level_win": first["win"],
            "est_over_true_render_gmean": geo_mean([r["est_over_true_render"] for r in rows]),
            "est_over_true_result_gmean": geo_mean([r["est_over_true_result"] for r in rows]),
            "est_over_true_result_range": [
                min(r["est_over_true_result"] for r in rows),
                max(r["est_over_true_result"] for r in rows)],
        }
    L.append("### Estimated versus true error (what the daemon reports, without a reference)\n")
    L.append("Estimated MSE per frame: render = mean Var[x]; denoised = mean SURE; proden = mean "
             "of the result's SURE, (1-a) Var[x] + a SURE - a (1-a) (y-x)^2, floored at mean "
             "(1-a)^2 Var[x] (the daemon's `estimated_mse`, `PipelineResult::estimated_error`). True MSE = MSE against the reference minus the reference's "
             "own variance. 1.0 is perfect; >1 over-estimates.\n")
    L += agreement_table(all_rows)
    L.append("")
    gm_r = geo_mean([r["est_over_true_render"] for rows in all_rows.values() for r in rows])
    gm_p = geo_mean([r["est_over_true_result"] for rows in all_rows.values() for r in rows])
    lo = min(r["est_over_true_result"] for rows in all_rows.values() for r in rows)
    hi = max(r["est_over_true_result"] for rows in all_rows.values() for r in rows)
    L.append(f"\nGeometric mean est/true over all scenes and levels: render {gm_r:.2f}, "
             f"proden {gm_p:.2f} (range {lo:.2f}..{hi:.2f}).\n")
    headline["est_over_true_render_gmean"] = gm_r
    headline["est_over_true_result_gmean"] = gm_p
    headline["est_over_true_result_range"] = [lo, hi]
    with open(os.path.join(out_dir, "accuracy.md"), "w") as f:
        f.write("\n".join(L) + "\n")
    with open(os.path.join(out_dir, "accuracy_summary.json"), "w") as f:
        json.dump(headline, f, indent=1, sort_keys=True)
    return headline


# --- self test ---------------------------------------------------------------------------------

def synthetic_rows(scene="synthetic"):
    rows = []
    for spp in (4, 8, 16, 32, 64, 128, 256, 512, 1024):
        t = 0.013 * spp
        up = 0.4
        r = {"scene": scene, "spp": spp, "passes": min(8, spp), "render_s": t,
             "render_s_measured": t,
             "read_accumulate_s": 0.05, "pipeline_s": up, "denoise_only_s": 0.2,
             "t_render": t, "t_denoised": t + 0.25, "t_result": t + 0.45}
        for k, scale, floor in (("render", 1.0, 0.0), ("denoised", 0.05, 2e-3),
                                ("result", 0.08, 5e-4)):
            mse = scale * 0.5 / spp + floor
            r.update({f"{k}_rmse": math.sqrt(mse), f"{k}_relmse": mse * 2, f"{k}_smape": mse ** 0.5,
                      f"{k}_mse": mse, f"{k}_mse_corrected": mse, f"est_{k}_mse": mse * 1.1,
                      f"est_over_true_{k}": 1.1})
        rows.append(r)
    return rows


def self_test():
    with tempfile.TemporaryDirectory() as d:
        rows = synthetic_rows()
        write_csv(os.path.join(d, "accuracy_synthetic.csv"), rows)
        back = read_csv(os.path.join(d, "accuracy_synthetic.csv"))
        assert len(back) == len(rows) and back[3]["spp"] == 32
        summ, cross = summarise(back, "relmse")
        assert summ[0]["win"] > 1.0, summ[0]
        # the render wins at high spp in this synthetic set (proden's fixed cost)
        assert cross is not None and cross["spp"] == 1024, cross
        want = 0.5 / (0.04 / 16 + 5e-4)
        assert abs(summ[2]["render_spp_equivalent"] - want) / want < 0.05, summ[2]
        plot("synthetic", back, os.path.join(d, "accuracy_synthetic.png"))
        assert os.path.getsize(os.path.join(d, "accuracy_synthetic.png")) > 10000
        h = report({"synthetic": back}, d)
        assert abs(h["est_over_true_result_gmean"] - 1.1) < 1e-6
        assert "stops paying off at **1024 spp" in open(os.path.join(d, "accuracy.md")).read()
    print("accuracy.py self-test: ok")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bin", default=os.environ.get("BENCH_BIN", os.path.join(ROOT, "build-bench",
                                                                              "bench")))
    ap.add_argument("--evaldata", default=os.environ.get("EVALDATA", "/work/evaldata"))
    ap.add_argument("--out", default=os.path.join(HERE, "results"))
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--time-model", choices=["median", "measured"], default="median",
                    help="render seconds of a level: spp x the set's median s/spp (default), or "
                         "the measured sum of the level's render_time headers")
    ap.add_argument("--reuse", action="store_true",
                    help="reuse accuracy_<scene>.jsonl instead of running eval_levels")
    ap.add_argument("--self-test", action="store_true")
    a = ap.parse_args()
    if a.self_test:
        self_test()
        return
    os.makedirs(a.out, exist_ok=True)
    binary = os.path.join(a.bin, "proden_eval_levels")
    all_rows = {}
    for scene in [s for s in a.scenes.split(",") if s]:
        sd = os.path.join(a.evaldata, scene)
        if not os.path.isdir(sd):
            print(f"skip {scene}: no {sd}", file=sys.stderr)
            continue
        raw = os.path.join(a.out, f"accuracy_{scene}.jsonl")
        if a.reuse and os.path.exists(raw):
            evals = [json.loads(l) for l in open(raw) if l.strip()]
        else:
            evals = run_eval(binary, sd, a.threads)
            with open(raw, "w") as f:
                for e in evals:
                    f.write(json.dumps(e) + "\n")
        rows = rows_for_scene(scene, sd, evals, a.time_model)
        write_csv(os.path.join(a.out, f"accuracy_{scene}.csv"), rows)
        plot(scene, rows, os.path.join(a.out, f"accuracy_{scene}.png"))
        all_rows[scene] = rows
    if not all_rows:
        raise SystemExit("no scenes evaluated")
    h = report(all_rows, a.out)
    print(json.dumps(h, indent=1))


if __name__ == "__main__":
    main()
