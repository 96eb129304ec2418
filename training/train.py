"""Train PDNet (docs/mixer_network.md) on the frames of $TRAINING_DATA.

Loss: SMAPE of the mixed z = x + alpha (y - x) against the reference,
      mean |z - r| / (|z| + |r| + 1e-2).  Adam + OneCycleLR.

  train.py --width 48 --steps 300 --max-lr 1e-3 --out training/runs/w48
"""
import os
# libgomp's default busy-waiting collapses under CPU contention (rendering in the
# background): 2 threads ran 5-10x slower than 1.  Must be set before torch loads.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
import argparse
import json
import os
import shlex
import sys
import time

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from pdnet import PDNet, make_inputs, mix  # noqa: E402
import dataset as ds  # noqa: E402
from evaluate import evaluate, format_table  # noqa: E402


def smape_loss(z, r):
    return (torch.abs(z - r) / (torch.abs(z) + torch.abs(r) + 1e-2)).mean()


def relmse_loss(z, r, y, cap=100.0):
    """relMSE with the denoised input y standing in for the reference in the weight,
    (z - r)^2 / (y^2 + 0.01), softly capped per element (cap * log1p(e / cap): a firefly keeps a
    bounded, non-zero gradient). The weight does not hold the reference, so the reference's own
    noise, independent of the inputs, only adds a constant to the expected loss (Noise2Noise);
    SMAPE's denominator holds the reference, and a grainy reference flattens it."""
    e = (z - r) ** 2 / (y * y + 1e-2)
    return (cap * torch.log1p(e / cap)).mean()


def training_loss(kind, z, r, y):
    if kind == "smape":
        return smape_loss(z, r)
    if kind == "relmse":
        return relmse_loss(z, r, y)
    return smape_loss(z, r) + relmse_loss(z, r, y)  # "smape+relmse"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--width", type=int, default=48)
    ap.add_argument("--steps", type=int, default=0, help="optimiser steps (overrides --epochs)")
    ap.add_argument("--epochs", type=float, default=0,
                    help="epochs; one epoch = (#train frames x #levels) / batch steps")
    ap.add_argument("--batch", type=int, default=12)
    ap.add_argument("--crop", type=int, default=64, help="square crop size (128 = full frame; 64 measured ~1.5x more pixels/s)")
    ap.add_argument("--max-lr", type=float, default=1e-3)
    ap.add_argument("--pct-start", type=float, default=0.25, help="OneCycleLR warm-up fraction")
    ap.add_argument("--clip", type=float, default=1.0, help="gradient-norm clip (0 = off)")
    ap.add_argument("--data", default=None, help="dataset root (default $TRAINING_DATA or /work/trainingdata)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--log-every", type=int, default=10)
    ap.add_argument("--val-every", type=int, default=0, help="validate every N steps (0 = only at the end)")
    ap.add_argument("--val-limit", type=int, default=0, help="use at most N val frames (0 = all)")
    ap.add_argument("--budget", type=float, default=0,
                    help="training seconds: run --calib steps at OneCycle's initial LR, measure the speed, "
                         "then size the OneCycle schedule to fill the budget (overrides --steps/--epochs)")
    ap.add_argument("--calib", type=int, default=-1,
                    help="steps at the constant initial LR before OneCycle starts (default 50 with --budget, "
                         "else 0); --steps N --calib C reproduces a --budget run that chose N")
    ap.add_argument("--time-limit", type=float, default=0,
                    help="stop after this many seconds of training (the schedule is cut short)")
    ap.add_argument("--no-val", action="store_true")
    ap.add_argument("--max-ref-noise", type=float, default=0.0,
                    help="drop training frame-levels whose reference noise is more than this share of "
                         "the denoised image's measured error (dataset.ref_noise_share; 0 = keep all)")
    ap.add_argument("--loss", default="smape", choices=["smape", "relmse", "smape+relmse"],
                    help="training loss (relmse: train.relmse_loss, weighted by the denoised input instead "
                         "of the reference; measured worse than smape on cornell: docs/mixer_network.md)")
    ap.add_argument("--ref-spp", type=int, default=int(os.environ.get("REF_SPP", "1024")),
                    help="the references' spp, for --max-ref-noise (render_set.py's REF_SPP)")
    args = ap.parse_args(argv)

    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    np.random.seed(args.seed)
    torch.use_deterministic_algorithms(True)
    rng = np.random.default_rng(args.seed)
    os.makedirs(args.out, exist_ok=True)
    command = " ".join(shlex.quote(a) for a in ["/usr/bin/python3", os.path.relpath(sys.argv[0])] + sys.argv[1:])

    root = ds.data_root(args.data)
    t0 = time.time()
    train_frames = ds.load_split(root, "train")
    val_frames = [] if args.no_val else ds.load_split(root, "val", limit=args.val_limit or None)
    if not train_frames:
        print(f"no training frames under {root}", file=sys.stderr)
        return 1
    data = ds.MixerDataset(train_frames, crop=args.crop, max_ref_noise=args.max_ref_noise,
                           ref_spp=args.ref_spp)
    steps = args.steps or max(1, int(round(args.epochs * len(data.pairs) / args.batch)))
    if args.budget:
        steps = 10 ** 9  # decided after the calibration steps
    levels = sorted({int(s) for f in train_frames for s in f["spp"]})
    print(f"data {root}: {len(train_frames)} train frames ({len(data.pairs)} frame-levels, spp {levels}), "
          f"{data.dropped} frame-levels dropped by --max-ref-noise, {len(val_frames)} val frames; loaded in {time.time() - t0:.1f}s; {steps} steps", flush=True)

    net = PDNet(args.width)
    opt = torch.optim.Adam(net.parameters(), lr=args.max_lr / 25.0)  # OneCycle's initial LR
    sched = None
    calib = args.calib if args.calib >= 0 else (50 if args.budget else 0)
    if args.budget and not args.time_limit:
        args.time_limit = 1.15 * args.budget

    def make_sched(total):
        return torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=args.max_lr, total_steps=total,
                                                   pct_start=args.pct_start)
    if not calib:
        sched = make_sched(steps)
    elif not args.budget:
        assert steps > calib
    log = open(os.path.join(args.out, "log.jsonl"), "w")

    def emit(rec):
        log.write(json.dumps(rec) + "\n")
        log.flush()

    def validate(step):
        res = evaluate(net, val_frames)
        emit({"type": "val", "step": step, "t": round(time.time() - t_start, 2), **res})
        print(f"[val step {step}]\n" + format_table(res), flush=True)
        return res

    emit({"type": "config", "command": command, "args": vars(args), "root": root,
          "train_frames": [f["name"] for f in train_frames], "val_frames": [f["name"] for f in val_frames],
          "steps": None if args.budget else steps, "params": sum(p.numel() for p in net.parameters())})
    t_start = time.time()
    net.train()
    window, curve = [], []
    stopped_early = False
    step = 0
    while step < steps:
        step += 1
        x, y, var, sure, ref = data.batch(rng, args.batch)
        _, alpha = net(make_inputs(x, y, var, sure))
        loss = training_loss(args.loss, mix(x, y, alpha), ref, y)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        gnorm = float(torch.nn.utils.clip_grad_norm_(net.parameters(), args.clip if args.clip > 0 else 1e30))
        opt.step()
        if sched is not None:
            sched.step()
        if calib and step == calib:
            rate = calib / (time.time() - t_start)
            if args.budget:
                steps = max(calib + 10, int(args.budget * rate * 0.97))
            sched = make_sched(steps - calib)
            emit({"type": "calibration", "step": step, "steps_per_s": rate, "steps": steps})
            print(f"calibration: {rate:.2f} steps/s -> {steps} steps", flush=True)
        window.append(float(loss))
        if step % args.log_every == 0 or step == steps:
            el = time.time() - t_start
            rec = {"type": "train", "step": step, "loss": float(np.mean(window)), "lr": opt.param_groups[0]["lr"],
                   "grad_norm": gnorm, "t": round(el, 2), "steps_per_s": step / el}
            emit(rec)
            curve.append((step, rec["loss"]))
            print(f"step {step}/{steps} loss {rec['loss']:.5f} lr {rec['lr']:.2e} |g| {gnorm:.3f} "
                  f"{rec['steps_per_s']:.3f} steps/s", flush=True)
            window = []
            torch.save(net.state_dict(), os.path.join(args.out, "last.pt"))
        if val_frames and args.val_every and step % args.val_every == 0 and step != steps:
            validate(step)
            net.train()
        if args.time_limit and step < steps and time.time() - t_start > args.time_limit:
            stopped_early = True
            print(f"time limit reached at step {step}", flush=True)
            break
    train_seconds = time.time() - t_start
    torch.save(net.state_dict(), os.path.join(args.out, "model.pt"))
    summary = {"command": command, "width": args.width, "max_lr": args.max_lr, "batch": args.batch,
               "budget_seconds": args.budget,
               "crop": args.crop, "seed": args.seed, "threads": args.threads,
               "steps": step, "planned_steps": steps, "stopped_early": stopped_early,
               "wall_seconds": round(train_seconds, 1), "steps_per_s": step / train_seconds,
               "dataset": {"root": root, "train_frames": len(train_frames), "val_frames": len(val_frames),
                           "frame_levels": len(data.pairs), "dropped_frame_levels": data.dropped,
                           "spp_levels": levels},
               "loss_curve": curve, "final_train_loss": curve[-1][1] if curve else None}
    if val_frames:
        res = validate(step)
        summary["validation"] = {"levels": res["levels"], "mean": res["mean"], "frames": res["frames"]}
    summary["total_wall_seconds"] = round(time.time() - t0, 1)
    if args.budget and not stopped_early:
        import re
        summary["reproduce"] = re.sub(r" --(budget|calib|time-limit) \S+", "", command) + f" --steps {steps} --calib {calib}"
    json.dump(summary, open(os.path.join(args.out, "summary.json"), "w"), indent=1)
    print(f"saved {args.out}/model.pt; {step} steps in {train_seconds:.0f}s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
