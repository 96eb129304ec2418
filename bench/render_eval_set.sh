#!/usr/bin/env bash
# Render a progressive-evaluation set of one Cycles sample scene.
#
#   bench/render_eval_set.sh SCENE OUTDIR [RES]
#
#   SCENE   cornell | textured_dof | glass | interior | path/to/scene.py (built on
#           samples/scenes/common.py)
#   OUTDIR  receives, all float32 multilayer EXR, RES x RES (RES default 256):
#             spp<L>/pass_00.exr .. pass_0{P-1}.exr  for L in LEVELS: P = min(8, L) passes
#                                                of L/P spp, seed L*100 + k + 1 (spp4 = 4
#                                                passes of 1 spp; spp1024 = 8 x 128 spp)
#             reference/pass_00.exr .. pass_07.exr  8 passes of 512 spp (4096 spp in all),
#                                                seeds 900001..900008
#             timings.tsv   file seed spp wall_s render_time render_s  (render_time is
#                           Blender's cycles.ViewLayer.render_time header, render_s the same
#                           in seconds)
#   Every seed is used by exactly one file of the set.
#
# Resumable: existing non-empty outputs are kept (FORCE=1 re-renders). Each pass is rendered
# to pass_0k.partial.exr, checked (readable, has the render_time header) and renamed.
# Environment: BLENDER (default: blender), FORCE=1 (re-renders; timings.tsv then has a second
#   line for the file, the last one counts),
#   PARTS=all (default) | levels (spp8..spp256 only) | reference (reference only),
#   LEVELS="8 16 32 64 128 256" (default; each 1..7 or a multiple of 8, below 9000; the bench
#   adds 4 512 1024), BLENDER_LOCK=FILE (run Blender under flock FILE: one render at a time
#   when several scripts share the machine).
set -euo pipefail

usage() { sed -n '2,26p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
[[ $# -ge 2 && $# -le 3 ]] || usage
SCENE=$1 OUTDIR=$2 RES=${3:-256}
[[ $RES =~ ^[0-9]+$ ]] || usage
PARTS=${PARTS:-all}
[[ $PARTS == all || $PARTS == levels || $PARTS == reference ]] || usage
LEVELS=${LEVELS:-8 16 32 64 128 256}
NPASS=8 REF_SPP=512 REF_SEED0=900000

HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
case $SCENE in
  *.py) SCRIPT=$(realpath "$SCENE") ;;
  *) SCRIPT=$HERE/../samples/scenes/$SCENE.py ;;
esac
[[ -f $SCRIPT ]] || { echo "no scene script $SCRIPT" >&2; exit 2; }
SCRIPT=$(realpath "$SCRIPT")
BLENDER=${BLENDER:-blender}
command -v oiiotool >/dev/null || { echo "oiiotool not found (apt-get install openimageio-tools)" >&2; exit 2; }

mkdir -p "$OUTDIR"
LOG=$OUTDIR/timings.tsv
[[ -s $LOG ]] || printf 'file\tseed\tspp\twall_s\trender_time\trender_s\n' > "$LOG"

# "mm:ss.cc" or "hh:mm:ss.cc" -> seconds
to_seconds() { awk -F: '{ s = 0; for (i = 1; i <= NF; i++) s = s * 60 + $i; printf "%.2f", s }' <<<"$1"; }

render() { # relpath seed spp
  local rel=$1 seed=$2 spp=$3
  local out=$OUTDIR/$rel
  local tmp=${out%.exr}.partial.exr
  if [[ -s $out && ${FORCE:-0} != 1 ]]; then
    echo "keep   $rel (exists)"
    return
  fi
  mkdir -p "$(dirname "$out")"
  rm -f "$tmp" "$tmp.partial"
  local t0 t1 wall rt
  t0=$(date +%s.%N)
  local lock=()
  [[ -n ${BLENDER_LOCK:-} ]] && lock=(flock "$BLENDER_LOCK")
  if ! "${lock[@]}" "$BLENDER" -b --factory-startup -noaudio -P "$SCRIPT" -- \
        --seed "$seed" --spp "$spp" --res "$RES" --out "$tmp" 2>&1 | grep '^PRODEN_RENDER' >/dev/null; then
    echo "FAILED $rel: rerun by hand:" >&2
    echo "  $BLENDER -b --factory-startup -noaudio -P $SCRIPT -- --seed $seed --spp $spp --res $RES --out $tmp" >&2
    exit 1
  fi
  t1=$(date +%s.%N)
  wall=$(awk -v a="$t0" -v b="$t1" 'BEGIN{printf "%.3f", b-a}')
  rt=$(oiiotool --info -v "$tmp" | sed -n 's/^ *cycles\.ViewLayer\.render_time: *"\(.*\)".*/\1/p' | head -n1)
  if [[ -z $rt ]]; then
    echo "FAILED $rel: $tmp has no cycles.ViewLayer.render_time header" >&2
    exit 1
  fi
  mv -f "$tmp" "$out"
  printf '%s\t%s\t%s\t%s\t%s\t%s\n' "$rel" "$seed" "$spp" "$wall" "$rt" "$(to_seconds "$rt")" >> "$LOG"
  printf 'render %-26s seed=%-6s spp=%-4s wall=%7ss render=%s\n' "$rel" "$seed" "$spp" "$wall" "$rt"
}

if [[ $PARTS != reference ]]; then
  for L in $LEVELS; do
    [[ $L =~ ^[0-9]+$ ]] && (( L >= 1 && (L < 8 || L % 8 == 0) && L < 9000 )) \
      || { echo "bad level $L (1..7 or a multiple of 8, below 9000)" >&2; exit 2; }
    P=$(( L < NPASS ? L : NPASS ))
    for (( k = 0; k < P; k++ )); do
      render "spp$L/$(printf 'pass_%02d.exr' "$k")" $(( L * 100 + k + 1 )) $(( L / P ))
    done
  done
fi
if [[ $PARTS != levels ]]; then
  for (( k = 0; k < NPASS; k++ )); do
    render "reference/$(printf 'pass_%02d.exr' "$k")" $(( REF_SEED0 + k + 1 )) "$REF_SPP"
  done
fi
