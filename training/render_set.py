#!/usr/bin/python3
"""Render and pack training/validation frames for the learned mixer (run with /usr/bin/python3).

For each frame (one random procedural scene, training/scenes/procedural.py):
  <root>/<split>/<frame>/slot{i}_chunk{j}.exr  i=0..7 pass slots, j=0..5 chunks of spp
                                               1,1,2,4,8,16 (slot i holds 1,2,4,8,16,32 spp
                                               after chunks 0..j), seed 1+16*i+j
  <root>/<split>/<frame>/reference.exr         1024 spp, seed 100000
  <root>/<split>/<frame>/level_{spp}.exr       `proden denoise --aov` of the passes of a level
  <root>/<split>/<frame>/frame.npz             x, y, var, sure, alpha_cf [L,3,H,W], ref [3,H,W], spp [L]
  <root>/<split>/<frame>/times.json            timings and the scene description
Levels: 4 = slots 0..3 chunk 0; 8 = slots 0..7 chunk 0; 16/32/64/128/256 = chunks 0..1/../0..5
of all 8 slots. Resumable: existing non-empty files are kept; a frame with frame.npz is skipped.
Root: /work/trainingdata (env TRAINING_DATA). A line per frame goes to <root>/generation_log.tsv.

    /usr/bin/python3 training/render_set.py --split val --count 8 --start 0
"""

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np
import OpenImageIO as oiio

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
SCENE = os.path.join(HERE, "scenes", "procedural.py")
PRODEN = os.environ.get("PRODEN", os.path.join(REPO, "build", "proden"))  # `make build`
# The denoiser whose output the inputs carry (`proden denoise --denoiser`); empty: proden's default.
DENOISER = os.environ.get("DENOISER", "")
BLENDER = os.environ.get("BLENDER", "blender")
# Share of the frames closed into a room lit only indirectly (procedural.py --room-prob; 0 = the
# open scenes of the first data sets, unchanged).
ROOM_PROB = os.environ.get("ROOM_PROB", "0")
SLOTS = 8
CHUNK_SPP = [1, 1, 2, 4, 8, 16]
REF_SPP = int(os.environ.get("REF_SPP", "1024"))
REF_SEED = 100000
SPLIT_BASE = {"train": 1000, "val": 9000}
LEVELS = [4, 8, 16, 32, 64, 128, 256]


def chunk_seed(i, j):
    return 1 + 16 * i + j


def level_files(fdir, level):
    if level == 4:
        return [os.path.join(fdir, "slot%d_chunk0.exr" % i) for i in range(4)]
    if level == 8:
        return [os.path.join(fdir, "slot%d_chunk0.exr" % i) for i in range(SLOTS)]
    nchunks = {16: 2, 32: 3, 64: 4, 128: 5, 256: 6}[level]
    return [os.path.join(fdir, "slot%d_chunk%d.exr" % (i, j))
            for i in range(SLOTS) for j in range(nchunks)]


def nonempty(p):
    return os.path.isfile(p) and os.path.getsize(p) > 0


def read_exr(path):
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise RuntimeError("cannot open %s: %s" % (path, oiio.geterror()))
    spec = inp.spec()
    px = inp.read_image(0, 0, 0, spec.nchannels, "float")
    inp.close()
    names = list(spec.channelnames)
    return names, np.asarray(px, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)


def rgb(names, px, prefix, path):
    idx = []
    for c in "RGB":
        n = prefix + c
        if n not in names:
            raise RuntimeError("%s: no channel %s (has %s)" % (path, n, names))
        idx.append(names.index(n))
    return np.ascontiguousarray(px[:, :, idx].transpose(2, 0, 1))


def render_missing(fdir, scene_seed, res, log):
    chunks = []
    for i in range(SLOTS):
        for j, spp in enumerate(CHUNK_SPP):
            out = os.path.join(fdir, "slot%d_chunk%d.exr" % (i, j))
            if not nonempty(out):
                chunks.append("%d:%d:%s" % (chunk_seed(i, j), spp, out))
    ref = os.path.join(fdir, "reference.exr")
    if not nonempty(ref):
        chunks.append("%d:%d:%s" % (REF_SEED, REF_SPP, ref))
    desc = None
    if not chunks:
        return 0.0, 0.0, 0, desc
    cmd = [BLENDER, "-b", "--factory-startup", "-noaudio", "-P", SCENE, "--",
           "--scene-seed", str(scene_seed), "--res", str(res), "--room-prob", ROOM_PROB]
    for c in chunks:
        cmd += ["--chunk", c]
    t0 = time.time()
    p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    wall = time.time() - t0
    render_s = 0.0
    for line in p.stdout.splitlines():
        if line.startswith("PRODEN_RENDER"):
            render_s += float(line.split("seconds=")[1].split()[0])
        elif line.startswith("PRODEN_SCENE"):
            desc = line[len("PRODEN_SCENE "):]
    with open(os.path.join(fdir, "blender.log"), "w") as f:
        f.write(p.stdout)
    if p.returncode != 0 or any(not nonempty(c.split(":", 2)[2]) for c in chunks):
        raise RuntimeError("blender failed (rc=%d), see %s/blender.log" % (p.returncode, fdir))
    log("  rendered %d files in %.1f s (render %.1f s)" % (len(chunks), wall, render_s))
    return wall, render_s, len(chunks), desc


def run_levels(fdir, log):
    t0 = time.time()
    for lv in LEVELS:
        out = os.path.join(fdir, "level_%d.exr" % lv)
        if nonempty(out):
            continue
        for attempt in range(30):  # the binary may be briefly missing during a rebuild
            if os.access(PRODEN, os.X_OK):
                break
            time.sleep(10)
        cmd = [PRODEN, "denoise", "--aov", "-q", "--out", out] + level_files(fdir, lv)
        if DENOISER:
            cmd[2:2] = ["--denoiser", DENOISER]
        p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        if p.returncode != 0 or not nonempty(out):
            raise RuntimeError("proden failed (rc=%d) for level %d: %s" % (p.returncode, lv, p.stdout[-2000:]))
    return time.time() - t0


def pack(fdir):
    arrs = {k: [] for k in ("x", "y", "var", "sure", "alpha_cf")}
    prefix = {"x": "render.", "y": "denoised.", "var": "mixvariance.", "sure": "sure.",
              "alpha_cf": "alpha."}
    for lv in LEVELS:
        path = os.path.join(fdir, "level_%d.exr" % lv)
        names, px = read_exr(path)
        for k in arrs:
            arrs[k].append(rgb(names, px, prefix[k], path))
    out = {k: np.stack(v).astype(np.float32) for k, v in arrs.items()}
    rpath = os.path.join(fdir, "reference.exr")
    names, px = read_exr(rpath)
    layer = [n for n in names if n.endswith(".Combined.R")][0][:-1]
    out["ref"] = rgb(names, px, layer, rpath).astype(np.float32)
    out["spp"] = np.array(LEVELS, dtype=np.int32)
    for k, v in out.items():
        if not np.all(np.isfinite(v)):
            raise RuntimeError("%s: non-finite values in %s" % (fdir, k))
    tmp = os.path.join(fdir, "frame.tmp.npz")
    np.savez_compressed(tmp, **out)
    os.replace(tmp, os.path.join(fdir, "frame.npz"))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--split", choices=sorted(SPLIT_BASE), required=True)
    ap.add_argument("--count", type=int, required=True)
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--deadline", type=float, default=0,
                    help="unix time: start no new frame after it (0 = none)")
    a = ap.parse_args()
    root = os.environ.get("TRAINING_DATA", "/work/trainingdata")
    os.makedirs(os.path.join(root, a.split), exist_ok=True)
    gl = os.path.join(root, "generation_log.tsv")
    if not os.path.exists(gl):
        with open(gl, "w") as f:
            f.write("date\tsplit\tframe\tscene_seed\tstatus\trender_wall_s\tproden_s\ttotal_s\tfiles_rendered\n")

    def log(msg):
        print(time.strftime("%H:%M:%S"), msg, flush=True)

    t_all = time.time()
    done = 0
    for k in range(a.start, a.start + a.count):
        if a.deadline and time.time() > a.deadline:
            log("deadline reached, stopping before frame %d" % k)
            break
        seed = SPLIT_BASE[a.split] + k
        frame = "scene%05d" % seed
        fdir = os.path.join(root, a.split, frame)
        if nonempty(os.path.join(fdir, "frame.npz")):
            log("%s/%s: done already" % (a.split, frame))
            continue
        os.makedirs(fdir, exist_ok=True)
        log("%s/%s: scene seed %d" % (a.split, frame, seed))
        t0 = time.time()
        status = "ok"
        wall = render_s = proden_s = 0.0
        nfiles = 0
        metrics = {}
        try:
            wall, render_s, nfiles, desc = render_missing(fdir, seed, a.res, log)
            proden_s = run_levels(fdir, log)
            out = pack(fdir)
            x256, ref = out["x"][-1], out["ref"]
            metrics = {"ref_mean": float(ref.mean()), "ref_max": float(ref.max()),
                       "relmse_x": [float(np.mean((v - ref) ** 2 / (ref ** 2 + 0.01))) for v in out["x"]],
                       "relmse_y": [float(np.mean((v - ref) ** 2 / (ref ** 2 + 0.01))) for v in out["y"]]}
            log("  packed: ref mean %.4f max %.2f; x256 mean %.4f; relMSE(x256) %.4g; "
                "relMSE(y256) %.4g" % (ref.mean(), ref.max(), x256.mean(),
                                       np.mean((x256 - ref) ** 2 / (ref ** 2 + 0.01)),
                                       np.mean((out["y"][-1] - ref) ** 2 / (ref ** 2 + 0.01))))
        except Exception as e:  # keep going with the next frame
            status = "FAILED: %s" % str(e).replace("\t", " ").replace("\n", " ")[:300]
            log("  " + status)
            desc = None
        total = time.time() - t0
        if status == "ok":
            done += 1
            tj = os.path.join(fdir, "times.json")
            if nfiles == 0 and os.path.exists(tj):  # repacked only: keep the render timings
                old = json.load(open(tj))
                wall, render_s = old.get("render_wall_s", 0.0), old.get("render_s", 0.0)
            with open(tj, "w") as f:
                json.dump({"scene_seed": seed, "res": a.res, "render_wall_s": round(wall, 3),
                           "render_s": round(render_s, 3), "proden_s": round(proden_s, 3),
                           "total_s": round(total, 3), "files_rendered": nfiles,
                           "chunk_spp": CHUNK_SPP, "slots": SLOTS, "ref_spp": REF_SPP,
                           "levels": LEVELS, "scene": desc, "metrics": metrics,
                           "date": time.strftime("%Y-%m-%dT%H:%M:%S")}, f, indent=1)
        with open(gl, "a") as f:
            f.write("%s\t%s\t%s\t%d\t%s\t%.1f\t%.1f\t%.1f\t%d\n" % (
                time.strftime("%Y-%m-%dT%H:%M:%S"), a.split, frame, seed, status, wall,
                proden_s, total, nfiles))
        log("  %s in %.1f s" % (status, total))
    log("%s: %d frames in %.1f s" % (a.split, done, time.time() - t_all))


if __name__ == "__main__":
    sys.exit(main())
