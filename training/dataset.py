"""Training/validation data for PDNet.

Layout: $TRAINING_DATA (default /work/trainingdata)/{train,val}/<frame>/frame.npz with float32
x, y, var, sure, alpha_cf [L,3,H,W], spp [L] (int), ref [3,H,W].  Only frames whose frame.npz
exists are complete; everything is loaded into memory.
"""
import os
import glob
import numpy as np
import torch

DEFAULT_ROOT = "/work/trainingdata"
KEYS = ("x", "y", "var", "sure", "alpha_cf")


def data_root(root=None):
    return root or os.environ.get("TRAINING_DATA", DEFAULT_ROOT)


def list_frames(root, split):
    return sorted(glob.glob(os.path.join(data_root(root), split, "*", "frame.npz")))


def _clean(a):
    a = np.asarray(a, dtype=np.float32)
    if not np.all(np.isfinite(a)):
        a = np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0)
    return np.ascontiguousarray(a)


def load_frame(path):
    with np.load(path) as z:
        f = {k: _clean(z[k]) for k in KEYS}
        f["ref"] = _clean(z["ref"])
        f["spp"] = np.asarray(z["spp"]).astype(np.int64).reshape(-1)
    f["name"] = os.path.basename(os.path.dirname(path))
    L = f["x"].shape[0]
    assert f["spp"].shape[0] == L, path
    for k in KEYS:
        assert f[k].shape == f["x"].shape, (path, k, f[k].shape)
    assert f["ref"].shape == f["x"].shape[1:], path
    return f


def load_split(root, split, limit=None):
    paths = list_frames(root, split)
    if limit:
        paths = paths[:limit]
    frames = []
    for p in paths:
        try:
            frames.append(load_frame(p))
        except Exception as e:  # a frame being written or malformed: skip, say so
            print(f"[dataset] skipping {p}: {e}", flush=True)
    return frames


def ref_noise_share(f, level, ref_spp=1024):
    """The reference's own noise as a share of the denoised image's measured error at one level,
    both in relMSE weights: the reference is a render of ref_spp samples, so its variance is the
    level's Var[x] times spp / ref_spp. Near 1, the training target is mostly the reference's
    noise (dark rooms lit only indirectly, whose 1024-spp reference is still grainy)."""
    ref = f["ref"].astype(np.float64)
    w = 1.0 / (ref * ref + 0.01)
    ref_var = f["var"][level].astype(np.float64) * (float(f["spp"][level]) / ref_spp)
    err = (f["y"][level].astype(np.float64) - ref) ** 2
    return float(np.mean(ref_var * w) / max(np.mean(err * w), 1e-30))


class MixerDataset:
    """Random (frame, level) samples with crops and the design's augmentations.

    Augmentation (design §2.3): random crop, flips, rot90, an RGB permutation shared by all
    inputs and the reference, and with probability 0.5 a swap x<->y together with var<->sure.
    """

    def __init__(self, frames, crop=128, augment=True, swap_prob=0.5, max_ref_noise=0.0, ref_spp=1024):
        assert frames, "no frames"
        self.frames = frames
        self.crop = crop
        self.augment = augment
        self.swap_prob = swap_prob
        self.pairs = [(i, l) for i, f in enumerate(frames) for l in range(f["x"].shape[0])
                      if not max_ref_noise or ref_noise_share(f, l, ref_spp) <= max_ref_noise]
        self.dropped = sum(f["x"].shape[0] for f in frames) - len(self.pairs)
        assert self.pairs, "every frame-level dropped by max_ref_noise"

    def sample(self, rng):
        fi, li = self.pairs[rng.integers(len(self.pairs))]
        f = self.frames[fi]
        H, W = f["ref"].shape[1:]
        c = min(self.crop, H, W)
        i0 = int(rng.integers(H - c + 1))
        j0 = int(rng.integers(W - c + 1))
        sl = (slice(None), slice(i0, i0 + c), slice(j0, j0 + c))
        x, y, var, sure = (f[k][li][sl] for k in ("x", "y", "var", "sure"))
        ref = f["ref"][sl]
        arrs = [x, y, var, sure, ref]
        if self.augment:
            if rng.random() < self.swap_prob:
                arrs = [y, x, sure, var, ref]
            perm = rng.permutation(3)
            k = int(rng.integers(4))
            fh = rng.random() < 0.5
            out = []
            for a in arrs:
                a = a[perm]
                if fh:
                    a = a[:, :, ::-1]
                a = np.rot90(a, k, axes=(1, 2))
                out.append(np.ascontiguousarray(a))
            arrs = out
        return arrs

    def batch(self, rng, n=12):
        samples = [self.sample(rng) for _ in range(n)]
        return [torch.from_numpy(np.stack([s[j] for s in samples])) for j in range(5)]


def make_synthetic(root, n_train=4, n_val=2, size=128, levels=(4, 8, 16, 32, 64, 128, 256), seed=0):
    """A small fake dataset with the real layout (for development without rendered data)."""
    rng = np.random.default_rng(seed)
    import torch.nn.functional as F
    for split, n in (("train", n_train), ("val", n_val)):
        for fi in range(n):
            d = os.path.join(root, split, f"synth{fi:03d}")
            os.makedirs(d, exist_ok=True)
            yy, xx = np.mgrid[0:size, 0:size] / size
            ref = np.stack([0.5 + 0.4 * np.sin(6 * xx + c + fi) * np.cos(4 * yy - c)
                            for c in range(3)]).astype(np.float32)
            ref[:, size // 3: size // 2, :] *= 3.0
            sig = 0.6 * np.sqrt(np.maximum(ref, 1e-3))
            xs, ys, vs, ss, acf = [], [], [], [], []
            for spp in levels:
                v = (sig ** 2 / spp).astype(np.float32)
                x = ref + rng.standard_normal(ref.shape).astype(np.float32) * np.sqrt(v)
                t = torch.from_numpy(x)[None]
                k = torch.ones(3, 1, 5, 5) / 25
                y = F.conv2d(F.pad(t, (2, 2, 2, 2), mode="replicate"), k, groups=3)[0].numpy()
                sure = ((y - x) ** 2 - v + 2 * v / 25).astype(np.float32)
                a = np.clip(v / (v + np.maximum(sure, 0) + 1e-8), 0, 1).astype(np.float32)
                xs.append(x); ys.append(y); vs.append(v); ss.append(sure); acf.append(a)
            np.savez(os.path.join(d, "frame.npz"), x=np.stack(xs), y=np.stack(ys),
                     var=np.stack(vs), sure=np.stack(ss), alpha_cf=np.stack(acf),
                     spp=np.array(levels, dtype=np.int32), ref=ref)


if __name__ == "__main__":
    import sys
    root = sys.argv[1] if len(sys.argv) > 1 else "/tmp/pdn/synth"
    make_synthetic(root)
    fr = load_split(root, "train")
    ds = MixerDataset(fr, crop=64)
    b = ds.batch(np.random.default_rng(0), 12)
    print(len(fr), [t.shape for t in b], [float(t.mean()) for t in b])
