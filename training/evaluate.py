"""Per-spp-level validation of PDNet against x, y and the closed-form mixer (before the t-test,
which lives in C++).  Full frames, all levels, of a split (default val).

  evaluate.py --model OUT/model.pt            (or a .pdnw)  [--data ROOT] [--split val]
"""
import os
# libgomp's default busy-waiting collapses under CPU contention (rendering in the
# background): 2 threads ran 5-10x slower than 1.  Must be set before torch loads.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
import argparse
import json
import os
import sys

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from pdnet import make_inputs, mix, load_model  # noqa: E402
import dataset as ds  # noqa: E402

METHODS = ("x", "y", "cf", "net")
METRICS = ("relmse", "smape", "rmse")


def _terms(i, r):
    d = i - r
    return {
        "relmse": (d * d / (r * r + 0.01)).sum(),
        "smape": (np.abs(d) / (np.abs(i) + np.abs(r) + 0.01)).sum(),
        "se": (d * d).sum(),
    }


@torch.no_grad()
def evaluate(net, frames):
    """Returns {"levels": {spp: {method: {metric: value}}}, "mean": {method: {metric}}, "frames": n}."""
    acc = {}
    was_training = net.training if net is not None else False
    if net is not None:
        net.eval()
    for f in frames:
        x, y, var, sure, acf = (f[k] for k in ("x", "y", "var", "sure", "alpha_cf"))
        ref = f["ref"][None]
        outs = {"x": x, "y": y, "cf": x + acf * (y - x)}
        if net is not None:
            t = [torch.from_numpy(a) for a in (x, y, var, sure)]
            _, alpha = net(make_inputs(*t))
            outs["net"] = mix(t[0], t[1], alpha).numpy()
        for li, spp in enumerate(f["spp"].tolist()):
            a = acc.setdefault(int(spp), {"n": 0})
            a["n"] += ref[0].size
            for m, img in outs.items():
                for k, v in _terms(img[li].astype(np.float64), ref[0].astype(np.float64)).items():
                    a.setdefault(m, {}).setdefault(k, 0.0)
                    a[m][k] += float(v)
    if net is not None and was_training:
        net.train()
    levels = {}
    for spp in sorted(acc):
        a = acc[spp]
        levels[spp] = {m: {"relmse": a[m]["relmse"] / a["n"], "smape": a[m]["smape"] / a["n"],
                           "rmse": float(np.sqrt(a[m]["se"] / a["n"]))}
                       for m in METHODS if m in a}
    methods = [m for m in METHODS if levels and m in next(iter(levels.values()))]
    mean = {m: {k: float(np.mean([levels[s][m][k] for s in levels])) for k in METRICS} for m in methods}
    return {"levels": {str(s): v for s, v in levels.items()}, "mean": mean, "frames": len(frames)}


def format_table(res):
    lv = res["levels"]
    rows = list(lv.keys()) + ["mean"]
    get = lambda r: res["mean"] if r == "mean" else lv[r]
    methods = [m for m in METHODS if m in res["mean"]]
    lines = [f"validation: {res['frames']} frames, full frame, before the t-test"]
    for k in METRICS:
        hdr = f"{k:>7} | spp  " + " ".join(f"{m:>10}" for m in methods)
        if "net" in methods:
            hdr += "   net/cf  net/min(x,y)"
        lines.append(hdr)
        for r in rows:
            g = get(r)
            s = f"{'':>7} | {r:>4} " + " ".join(f"{g[m][k]:10.5f}" for m in methods)
            if "net" in methods:
                s += f"  {g['net'][k] / max(g['cf'][k], 1e-30):7.3f}  {g['net'][k] / max(min(g['x'][k], g['y'][k]), 1e-30):8.3f}"
            lines.append(s)
    return "\n".join(lines)


def markdown_table(res, metric):
    methods = [m for m in METHODS if m in res["mean"]]
    out = ["| spp | " + " | ".join(methods) + (" | net/cf |" if "net" in methods else " |"),
           "|---" * (len(methods) + 1 + ("net" in methods)) + "|"]
    for r in list(res["levels"].keys()) + ["mean"]:
        g = res["mean"] if r == "mean" else res["levels"][r]
        s = f"| {r} | " + " | ".join(f"{g[m][metric]:.5f}" for m in methods)
        if "net" in methods:
            s += f" | {g['net'][metric] / max(g['cf'][metric], 1e-30):.3f}"
        out.append(s + " |")
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--model", help="model.pt (state_dict) or .pdnw; omit for x/y/cf only")
    ap.add_argument("--data", default=None)
    ap.add_argument("--split", default="val")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--json", help="write the result here")
    ap.add_argument("--markdown", action="store_true")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    net = None
    if args.model:
        if args.model.endswith(".pdnw"):
            from export import model_from_pdnw
            _, net = model_from_pdnw(args.model)
        else:
            net = load_model(args.model)
    frames = ds.load_split(args.data, args.split)
    if not frames:
        print("no frames found", file=sys.stderr)
        return 1
    res = evaluate(net, frames)
    print(format_table(res))
    if args.markdown:
        for k in METRICS:
            print(f"\n{k}:\n" + markdown_table(res, k))
    if args.json:
        json.dump(res, open(args.json, "w"), indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
