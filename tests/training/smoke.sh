#!/usr/bin/env bash
# End-to-end check of the learned mixer's training chain on a tiny scale (ctest -L training):
# Blender renders one procedural train frame (a closed room lit only indirectly: ROOM_PROB=1) and
# one validation frame (an open scene; 24x24, 8-spp reference), proden computes their inputs, PyTorch trains a width-8 network for a few steps, export.py
# writes .pdnw + a parity fixture, the C++ parity test checks the fixture against the C++
# inference, and `proden denoise --mixer network --weights` runs with the exported file.
#
#   tests/training/smoke.sh PRODEN_BINARY UNIT_TEST_BINARY SAMPLES_DIR
set -euo pipefail
PRODEN=$1 UNIT=$2 SAMPLES=$3
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
PY=/usr/bin/python3
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
export TRAINING_DATA=$tmp/data REF_SPP=8 PRODEN

$PY "$HERE/training/render_set.py" --split val --count 1 --res 24
ROOM_PROB=1 $PY "$HERE/training/render_set.py" --split train --count 1 --res 24
for f in "$tmp"/data/val/scene09000/frame.npz "$tmp"/data/train/scene01000/frame.npz; do
  [[ -s $f ]] || { echo "smoke: $f was not produced" >&2; exit 1; }
done
$PY - "$tmp/data/train/scene01000/frame.npz" <<'PYEOF'
import sys, numpy as np
d = np.load(sys.argv[1])
for k in ("x", "y", "var", "sure", "alpha_cf"):
    assert d[k].shape == (7, 3, 24, 24), (k, d[k].shape)
    assert np.isfinite(d[k]).all(), k
assert d["ref"].shape == (3, 24, 24) and d["ref"].mean() > 0
assert list(d["spp"]) == [4, 8, 16, 32, 64, 128, 256]
PYEOF
# The room was built where asked, and only there.
grep -q "'room'" "$tmp/data/train/scene01000/times.json" || { echo "smoke: train frame is no room" >&2; exit 1; }
if grep -q "'room'" "$tmp/data/val/scene09000/times.json"; then echo "smoke: val frame is a room" >&2; exit 1; fi

# --max-ref-noise drops exactly the frame-levels whose reference noise share is above it: a
# threshold between the frame's smallest and largest share keeps some and drops some. (This run
# also trains with the relMSE loss term.)
thr=$(cd "$HERE/training" && $PY -c "
import dataset as ds, numpy as np
f = ds.load_frame('$tmp/data/train/scene01000/frame.npz')
s = sorted(ds.ref_noise_share(f, l, 8) for l in range(7))
assert s[0] < s[-1], s
print((s[0] + s[-1]) / 2)")
$PY "$HERE/training/train.py" --width 8 --steps 2 --batch 2 --crop 16 --out "$tmp/run_ref" \
    --data "$tmp/data" --threads 2 --no-val --max-ref-noise "$thr" --ref-spp 8 --loss smape+relmse
(cd "$HERE/training" && $PY - "$tmp" "$thr" <<'PYEOF'
import json, sys
import dataset as ds
tmp, thr = sys.argv[1], float(sys.argv[2])
f = ds.load_frame(tmp + "/data/train/scene01000/frame.npz")
want = sum(ds.ref_noise_share(f, l, 8) > thr for l in range(7))
got = json.load(open(tmp + "/run_ref/summary.json"))["dataset"]["dropped_frame_levels"]
assert 0 < want < 7 and got == want, (got, want, thr)
PYEOF
)

$PY "$HERE/training/train.py" --width 8 --steps 10 --batch 2 --crop 16 --out "$tmp/run" \
    --data "$tmp/data" --threads 2
$PY "$HERE/training/export.py" --model "$tmp/run/model.pt" --weights "$tmp/w8.pdnw" \
    --fixture "$tmp/f8.bin" --data "$tmp/data" --crop 16x20
$PY "$HERE/training/export.py" --verify "$tmp/w8.pdnw" --verify-fixture "$tmp/f8.bin"

# The C++ inference against PyTorch on the freshly exported network.
PRODEN_TEST_WEIGHTS="$tmp/w8.pdnw" PRODEN_TEST_FIXTURE="$tmp/f8.bin" "$UNIT" "[parity]"

out=$tmp/out.exr
"$PRODEN" denoise -q --json --mixer network --weights "$tmp/w8.pdnw" --out "$out" \
    "$SAMPLES"/renders/cornell/pass_0*.exr > "$tmp/summary.json"
$PY - "$tmp/summary.json" <<'PYEOF'
import json, sys
j = json.load(open(sys.argv[1]))
assert j["pipeline"]["mixer"] == "network-w8", j["pipeline"]
assert j["pipeline"]["weights"].endswith("w8.pdnw"), j["pipeline"]
PYEOF
echo "training smoke: ok"
