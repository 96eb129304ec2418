#!/usr/bin/env bash
# Render K independent Cycles passes of one frame plus a high-spp reference.
#
#   samples/render_cycles.sh SCENE OUTDIR PASSES SPP REF_SPP [--half]
#
#   SCENE    cornell | textured_dof | path/to/scene.py (a script built on scenes/common.py)
#   OUTDIR   receives pass_00.exr .. pass_{PASSES-1}.exr (seeds 1..PASSES) and reference.exr
#            (seed 100000, REF_SPP samples, always float32); REF_SPP=0 skips the reference
#   --half   write the passes as half-float EXR (the reference stays float32)
#
# Existing non-empty outputs are kept (delete them or set FORCE=1 to re-render).
# Each render is logged to OUTDIR/render_times.tsv: file seed spp half wall_s render_s.
# Environment: BLENDER (default: blender), RES (default: 128), FORCE=1.
set -euo pipefail

usage() { sed -n '2,13p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
[[ $# -ge 5 && $# -le 6 ]] || usage
SCENE=$1 OUTDIR=$2 PASSES=$3 SPP=$4 REF_SPP=$5
HALF=""
if [[ $# -eq 6 ]]; then
  [[ $6 == --half ]] || usage
  HALF=--half
fi
[[ $PASSES =~ ^[0-9]+$ && $SPP =~ ^[0-9]+$ && $REF_SPP =~ ^[0-9]+$ ]] || usage
(( PASSES <= 99999 )) || { echo "PASSES too large (seeds would reach the reference seed)" >&2; exit 2; }

HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
case $SCENE in
  *.py) SCRIPT=$(realpath "$SCENE") ;;
  *) SCRIPT=$HERE/scenes/$SCENE.py ;;
esac
[[ -f $SCRIPT ]] || { echo "no scene script $SCRIPT" >&2; exit 2; }
BLENDER=${BLENDER:-blender}
RES=${RES:-128}
REF_SEED=100000
mkdir -p "$OUTDIR"
LOG=$OUTDIR/render_times.tsv
[[ -f $LOG ]] || printf 'file\tseed\tspp\thalf\twall_s\trender_s\n' > "$LOG"

render() { # file seed spp halfflag
  local out=$OUTDIR/$1 seed=$2 spp=$3 half=$4
  if [[ -s $out && ${FORCE:-0} != 1 ]]; then
    echo "keep   $out (exists)"
    return
  fi
  local t0 t1 line rs hb=0
  [[ -n $half ]] && hb=1
  t0=$(date +%s.%N)
  if ! line=$("$BLENDER" -b --factory-startup -noaudio -P "$SCRIPT" -- \
        --seed "$seed" --spp "$spp" --res "$RES" --out "$out" $half 2>&1 | grep '^PRODEN_RENDER'); then
    echo "FAILED $out: rerun by hand:" >&2
    echo "  $BLENDER -b --factory-startup -noaudio -P $SCRIPT -- --seed $seed --spp $spp --res $RES --out $out $half" >&2
    exit 1
  fi
  t1=$(date +%s.%N)
  rs=$(sed -n 's/.*seconds=\([0-9.]*\).*/\1/p' <<<"$line")
  local wall
  wall=$(awk -v a="$t0" -v b="$t1" 'BEGIN{printf "%.3f", b-a}')
  printf '%s\t%s\t%s\t%s\t%s\t%s\n' "$1" "$seed" "$spp" "$hb" "$wall" "$rs" >> "$LOG"
  printf 'render %-16s seed=%-6s spp=%-5s %s wall=%ss render=%ss\n' "$1" "$seed" "$spp" "${half:-float}" "$wall" "$rs"
}

for (( k = 0; k < PASSES; k++ )); do
  render "$(printf 'pass_%02d.exr' "$k")" $((k + 1)) "$SPP" "$HALF"
done
if (( REF_SPP > 0 )); then
  render reference.exr "$REF_SEED" "$REF_SPP" ""
fi
