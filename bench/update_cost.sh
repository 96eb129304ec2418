#!/usr/bin/env bash
# A full 1080p update on a real Cycles frame against one more Cycles sample per pixel of the same
# frame, measured in one run (issue 12: "the fast path ... <= 0.5x one more Cycles spp ... on the
# bench's cornell and interior frames").
#
#   bench/update_cost.sh [--bin DIR] [--out DIR] [--threads N] [--repeat N] SCENE...
#
# Per scene (samples/scenes/<SCENE>.py, 1920x1080 by bench/cycles_frame.py): renders passes of
# 2, 2, 1 and 4 spp with distinct seeds; one more spp = (render_time(4 spp) - render_time(1 spp))
# / 3 (Blender's cycles.ViewLayer.render_time: path tracing only, no start-up, sync or BVH
# build); then proden_bench_pipeline on those four passes (the 4-spp pass is the one read and
# added timed) with --cycles-spp-seconds, under the daemon's heap policy. Writes
# DIR/update_<SCENE>.txt and .json (default DIR bench/results) and DIR/cycles_1080p_<SCENE>.json.
# Environment: BLENDER (default blender), BLENDER_LOCK=FILE (Blender under flock FILE),
# UPDATE_ARGS (more harness flags).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

BIN=build/bench OUT=bench/results THREADS=$(nproc) REPEAT=3
while [[ $# -gt 0 ]]; do
  case $1 in
    --bin) BIN=$2; shift 2 ;;
    --out) OUT=$2; shift 2 ;;
    --threads) THREADS=$2; shift 2 ;;
    --repeat) REPEAT=$2; shift 2 ;;
    -h|--help) sed -n '2,15p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    -*) echo "unknown option $1" >&2; exit 2 ;;
    *) break ;;
  esac
done
[[ $# -ge 1 ]] || { echo "usage: $0 [--bin DIR] [--out DIR] [--threads N] [--repeat N] SCENE..." >&2; exit 2; }
BLENDER=${BLENDER:-blender}
lock=()
[[ -n ${BLENDER_LOCK:-} ]] && lock=(flock "$BLENDER_LOCK")
mkdir -p "$OUT"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

header_seconds() { # EXR -> Blender render_time in seconds
  oiiotool --info -v "$1" | sed -n 's/^ *cycles\.ViewLayer\.render_time: *"\(.*\)".*/\1/p' | head -n1 |
    awk -F: '{ s = 0; for (i = 1; i <= NF; i++) s = s * 60 + $i; printf "%.2f", s }'
}

for scene in "$@"; do
  [[ -f samples/scenes/$scene.py ]] || { echo "no scene samples/scenes/$scene.py" >&2; exit 2; }
  echo "== $scene: Cycles passes at 1920x1080"
  # name:spp:seed; the last is the pass the update reads.
  for p in a:2:31 b:2:32 c1:1:8 c4:4:11; do
    IFS=: read -r name spp seed <<<"$p"
    PRODEN_SCENE=$scene PRODEN_W=1920 PRODEN_H=1080 "${lock[@]}" "$BLENDER" -b --factory-startup \
      -noaudio -P bench/cycles_frame.py -- --seed "$seed" --spp "$spp" --res 1920 \
      --out "$tmp/$name.exr" > "$tmp/blender_$name.log" 2>&1 \
      || { cat "$tmp/blender_$name.log" >&2; exit 1; }
  done
  t1=$(header_seconds "$tmp/c1.exr")
  t4=$(header_seconds "$tmp/c4.exr")
  one=$(awk -v a="$t1" -v b="$t4" 'BEGIN { printf "%.4f", (b - a) / 3 }')
  printf '{"scene": "%s", "width": 1920, "height": 1080, "render_time_1spp": %s, "render_time_4spp": %s, "one_more_spp_seconds": %s}\n' \
    "$scene" "$t1" "$t4" "$one" > "$OUT/cycles_1080p_$scene.json"
  echo "   1 spp $t1 s, 4 spp $t4 s -> one more spp $one s"
  echo "== $scene: the full update on that frame ($THREADS threads, median of $REPEAT warm runs)"
  # The daemon's heap policy (service/daemon/memory.cpp: blocks below 32 MiB from the heap, no
  # trimming, 4 arenas), which the harness does not set itself.
  # shellcheck disable=SC2086
  GLIBC_TUNABLES=glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=2147483647:glibc.malloc.arena_max=4 \
  "$BIN/proden_bench_pipeline" --pass "$tmp/a.exr" --pass "$tmp/b.exr" --pass "$tmp/c1.exr" \
    --pass "$tmp/c4.exr" --no-mc --threads "$THREADS" --repeat "$REPEAT" \
    --cycles-spp-seconds "$one" --tmp "$tmp" --json "$OUT/update_$scene.json" ${UPDATE_ARGS:-} \
    | sed "s|$tmp/||g" | tee "$OUT/update_$scene.txt"
  sed -i "s|$tmp/||g" "$OUT/update_$scene.json"
done
