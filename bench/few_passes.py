#!/usr/bin/env python3
"""Few-pass frames (docs/pipeline.md, "Few passes"): the same samples of a level merged into
2, 3, 4 and 8 passes (`proden_eval_levels --passes N`), result against the better of render and
denoised, in relMSE and SMAPE. Optionally a second build (--baseline-bin) for a before/after table.

  bench/few_passes.py --bin build/bench --evaldata /work/evaldata \\
      --scenes cornell,glass,interior,textured_dof --levels 8,32,128,512 --passes 2,3,4,8 \\
      [--baseline-bin OLD/build/bench] --out bench/results/few_passes.md

Writes the markdown table (--out) and the raw rows (same name, .jsonl).
"""
import argparse
import json
import os
import subprocess
import sys

LIMIT = 1.02  # issue 10: result <= 1.02 x min(render, denoised)


def run(binary, scene_dir, levels, passes, threads):
    cmd = [os.path.join(binary, "proden_eval_levels"), "--scene", scene_dir, "--levels",
           ",".join(map(str, levels)), "--passes", str(passes), "--json"]
    if threads:
        cmd += ["--threads", str(threads)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return [json.loads(line) for line in out.splitlines() if line.startswith("{")]


def ratio(row, metric):
    best = min(row["render"][metric], row["denoised"][metric])
    return row["result"][metric] / best if best > 0 else float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", required=True, help="build dir with proden_eval_levels")
    ap.add_argument("--baseline-bin", help="a second build to compare against (before)")
    ap.add_argument("--evaldata", default="/work/evaldata")
    ap.add_argument("--scenes", default="cornell,glass,interior,textured_dof")
    ap.add_argument("--levels", default="8,32,128,512")
    ap.add_argument("--passes", default="2,3,4,8")
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--out", required=True)
    ap.add_argument("--reuse", action="store_true", help="re-tabulate the .jsonl next to --out")
    a = ap.parse_args()
    levels = [int(x) for x in a.levels.split(",")]
    counts = [int(x) for x in a.passes.split(",")]
    rows = []
    jsonl = os.path.splitext(a.out)[0] + ".jsonl"
    if a.reuse:
        with open(jsonl) as fi:
            rows = [json.loads(line) for line in fi]
    for scene in a.scenes.split(",") if not a.reuse else []:
        d = os.path.join(a.evaldata, scene)
        if not os.path.isdir(os.path.join(d, "reference")):
            print(f"skip {scene}: no reference in {d}", file=sys.stderr)
            continue
        for p in counts:
            for tag, binary in (("after", a.bin), ("before", a.baseline_bin)):
                if not binary:
                    continue
                for r in run(binary, d, levels, p, a.threads):
                    r["build"] = tag
                    rows.append(r)
                print(f"{scene} {p} passes ({tag}) done", file=sys.stderr)
    if not a.reuse:
        with open(jsonl, "w") as fo:
            for r in rows:
                fo.write(json.dumps(r) + "\n")

    def find(build, scene, spp, passes):
        for r in rows:
            if (r["build"], r["scene"], r["spp"], r["passes"]) == (build, scene, spp, passes):
                return r
        return None

    before = any(r["build"] == "before" for r in rows)
    L = ["## Few passes (`bench/few_passes.py`)", "",
         "Each level's passes (P = min(8, L) of L/P spp) merged into N chunks of the same total "
         "spp; default pipeline (NL-means with features, closed-form Stein mixer, t-test). "
         "*ratio* = result / min(render, denoised) (issue 10 asks <= 1.02 for N = 2, 3, 4)"
         + ("; *before* = the same tool on the branch point (Cornish-Fisher threshold, the "
            "denoiser reading each pixel's own variance, one mixer window): compare the absolute "
            "numbers." if before else ".") + "",
         "",
         "Command: `bench/few_passes.py --bin " + a.bin
         + (f" --baseline-bin {a.baseline_bin}" if a.baseline_bin else "")
         + f" --evaldata {a.evaldata} --scenes {a.scenes} --levels {a.levels} --passes {a.passes}"
         + f" --out {a.out}`", ""]
    worst = {}
    for scene in dict.fromkeys(r["scene"] for r in rows):
        L.append(f"**{scene}**\n")
        head = ("| spp | N | relMSE render | denoised | result | ratio | SMAPE render | denoised "
                "| result | ratio |")
        sep = "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
        if before:
            head += " before: relMSE denoised | result | SMAPE result |"
            sep += "---:|---:|---:|"
        L += [head, sep]
        for spp in sorted({r["spp"] for r in rows if r["scene"] == scene}):
            for p in counts:
                r = find("after", scene, spp, p)
                if r is None:
                    continue
                rr, rs = ratio(r, "relmse"), ratio(r, "smape")
                if p <= 4:
                    w = worst.setdefault(scene, [0, 0])
                    w[0], w[1] = max(w[0], rr), max(w[1], rs)
                mark = lambda v: f"**{v:.3f}**" if v > LIMIT else f"{v:.3f}"
                line = (f"| {spp:.0f} | {r['passes']} | {r['render']['relmse']:.4g} | "
                        f"{r['denoised']['relmse']:.4g} | {r['result']['relmse']:.4g} | "
                        f"{mark(rr)} | {r['render']['smape']:.4g} | {r['denoised']['smape']:.4g} | "
                        f"{r['result']['smape']:.4g} | {mark(rs)} |")
                b = find("before", scene, spp, p) if before else None
                if b is not None:
                    line += (f" {b['denoised']['relmse']:.4g} | {b['result']['relmse']:.4g} | "
                             f"{b['result']['smape']:.4g} |")
                L.append(line)
        L.append("")
    if worst:
        L.append("Worst ratio over N = 2, 3, 4: " + "; ".join(
            f"{s} relMSE {w[0]:.3f}, SMAPE {w[1]:.3f}" for s, w in worst.items()) + ".\n")
    with open(a.out, "w") as fo:
        fo.write("\n".join(L))
    print(f"wrote {a.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
