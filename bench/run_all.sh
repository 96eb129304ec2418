#!/usr/bin/env bash
# Regenerates every benchmark result and bench/RESULTS.md (what `make bench` runs after building).
#
#   bench/run_all.sh
#
# Environment:
#   BUILD_DIR    build tree with bench/proden_* (default build-bench)
#   EVALDATA     evaluation sets, outside the repo (default /work/evaldata); missing levels and
#                references are rendered with bench/render_eval_set.sh (slow on a fresh machine:
#                ~10 min of Cycles per scene at 256x256 plus ~10 min per reference)
#   SCENES       default "cornell textured_dof glass interior"
#   LEVELS       default "4 8 16 32 64 128 256 512 1024"
#   RES          eval-set resolution (default 256)
#   BLENDER, BLENDER_LOCK   passed to render_eval_set.sh and update_cost.sh (BLENDER_LOCK=FILE:
#                one Blender at a time)
#   SKIP_RENDER=1    use the eval sets as they are
#   SKIP_ACCURACY=1  keep bench/results/accuracy* (REUSE_ACCURACY=1: re-plot from the .jsonl)
#   SKIP_PERF=1      keep bench/results/perf.*, micro.*, update_* and cycles_1080p*   PERF_ARGS:
#                extra bench_pipeline args (UPDATE_ARGS: bench/update_cost.sh's)
#   SKIP_SAVINGS=1   keep bench/results/savings.md, mixers_*.md and levels_* (bench/savings.py
#                    and bench/mixers.py --reuse re-tabulate them)
#   SKIP_NFOR=1      keep bench/results/nfor_* (NFOR's speed against NL-means and its evaluation
#                    against the references, docs/nfor.md)
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
BUILD_DIR=${BUILD_DIR:-build-bench}
BIN=$BUILD_DIR/bench
EVALDATA=${EVALDATA:-/work/evaldata}
SCENES=${SCENES:-cornell textured_dof glass interior}
LEVELS=${LEVELS:-4 8 16 32 64 128 256 512 1024}
RES=${RES:-256}
OUT=bench/results
PY=/usr/bin/python3
BLENDER=${BLENDER:-blender}
mkdir -p "$OUT"

if [[ ${SKIP_RENDER:-0} != 1 ]]; then
  for s in $SCENES; do
    echo "== eval set $s ($EVALDATA/$s)"
    LEVELS="$LEVELS" bench/render_eval_set.sh "$s" "$EVALDATA/$s" "$RES" | { grep -v '^keep' || true; }
  done
fi

if [[ ${SKIP_ACCURACY:-0} != 1 ]]; then
  reuse=()
  [[ ${REUSE_ACCURACY:-0} == 1 ]] && reuse=(--reuse)
  echo "== accuracy versus time"
  $PY bench/accuracy.py --bin "$BIN" --evaldata "$EVALDATA" --out "$OUT" \
      --scenes "$(tr ' ' ',' <<<"$SCENES")" "${reuse[@]}" > /dev/null
fi

if [[ ${SKIP_PERF:-0} != 1 ]]; then
  # One more Cycles sample per pixel of a 1920x1080 frame, and the full update on that real frame,
  # for cornell and interior (bench/update_cost.sh: render_time(4 spp) - render_time(1 spp), over
  # 3; Blender's render_time excludes start-up, sync and BVH build). The synthetic harness below
  # compares with cornell's.
  echo "== full 1080p update on real Cycles frames against one more spp"
  BLENDER=$BLENDER bench/update_cost.sh --bin "$BIN" --out "$OUT" cornell interior
  cp "$OUT/cycles_1080p_cornell.json" "$OUT/cycles_1080p.json"
  one=$($PY -c 'import json, sys; print(json.load(open(sys.argv[1]))["one_more_spp_seconds"])' \
    "$OUT/cycles_1080p.json")
  echo "== pipeline harness (1080p, 4K; 1 and $(nproc) threads)"
  "$BIN/proden_bench_pipeline" --cycles-spp-seconds "$one" --json "$OUT/perf.json" \
      ${PERF_ARGS:-} | tee "$OUT/perf.txt"
  echo "== learned-mixer inference (1080p; widths 48 and 24 and the built-in weights)"
  "$BIN/proden_bench_network" --width 48 --width 24 --weights training/weights/pdnet.pdnw \
      --json "$OUT/network.json" | tee "$OUT/network.txt"
  if [[ -x $BIN/proden_micro_kernels ]]; then
    echo "== Google Benchmark microbenchmarks"
    "$BIN/proden_micro_kernels" --benchmark_min_time=0.3 2>&1 | tee "$OUT/micro.txt"
  fi
fi

if [[ ${SKIP_NFOR:-0} != 1 ]]; then
  echo "== NFOR against NL-means, same run (1920x1080, $(nproc) threads)"
  "$BIN/proden_bench_nfor" --threads "$(nproc)" --repeat 2 --extras --json "$OUT/nfor_speed.json" |
    tee "$OUT/nfor_speed.txt"
  for s in $SCENES; do
    echo "== NFOR stages and error estimates: $s"
    "$BIN/proden_nfor_eval" --scene "$EVALDATA/$s" --json > "$OUT/nfor_eval_$s.jsonl"
  done
  $PY bench/nfor_results.py
fi

if [[ ${SKIP_SAVINGS:-0} != 1 ]]; then
  echo "== sample savings (render, NL-means, NFOR, proden on each, the cascade)"
  $PY bench/savings.py --bin "$BIN" --evaldata "$EVALDATA" --scenes "$(tr ' ' ',' <<<"$SCENES")"
  echo "== both mixers on NFOR and on the cascade"
  for d in nfor cascade; do
    $PY bench/mixers.py --denoiser $d --bin "$BIN" --evaldata "$EVALDATA" \
        --scenes "$(tr ' ' ',' <<<"$SCENES")" \
        --weights nfor-w48=training/weights/pdnet_nfor_w48.pdnw > /dev/null
  done
fi

echo "== bench/RESULTS.md"
$PY bench/make_results.py
