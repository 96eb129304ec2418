#!/usr/bin/env bash
# Render independent POV-Ray 3.7 passes of samples/povray/scene.pov (1 sample per pixel each).
#
#   samples/render_povray.sh OUTDIR PASSES [REF_PASSES]
#
#   OUTDIR      receives pass_00.exr .. pass_{PASSES-1}.exr (half RGB OpenEXR, +FE) for pass
#               numbers 0..PASSES-1, and pass_00.hdr (Radiance HDR, +FH) of pass 0
#   REF_PASSES  if > 0, also reference.exr = float32 mean of REF_PASSES further passes numbered
#               1000, 1001, ... (disjoint from the passes above); default 0
#
# The pass number reaches the scene as Declare=Pass=<n>; scene.pov derives all of its randomness
# from it (see povray/proden_pass.inc and README.md). Same pass number => identical image (+WT1).
# Existing non-empty outputs are kept (FORCE=1 re-renders). Log: OUTDIR/render_times.tsv.
# Environment: POVRAY (default: povray), RES (default: 128), SCENE (default: povray/scene.pov).
set -euo pipefail

usage() { sed -n '2,14p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
[[ $# -ge 2 && $# -le 3 ]] || usage
OUTDIR=$1 PASSES=$2 REF_PASSES=${3:-0}
[[ $PASSES =~ ^[0-9]+$ && $REF_PASSES =~ ^[0-9]+$ ]] || usage
(( PASSES <= 1000 )) || { echo "PASSES must be <= 1000 (1000.. are reference passes)" >&2; exit 2; }

HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
SCENE=$(realpath "${SCENE:-$HERE/povray/scene.pov}")
SCENEDIR=$(dirname "$SCENE")
POVRAY=${POVRAY:-povray}
RES=${RES:-128}
mkdir -p "$OUTDIR"
OUTDIR=$(realpath "$OUTDIR")
LOG=$OUTDIR/render_times.tsv
[[ -f $LOG ]] || printf 'file\tpass\tspp\tformat\twall_s\n' > "$LOG"

# pov FILE PASS FORMAT(+FE|+FH) [log]
pov() {
  local out=$1 pass=$2 fmt=$3 dolog=${4:-1}
  local tmp=${out%.*}.partial.${out##*.} t0 t1 wall  # povray appends an extension otherwise
  t0=$(date +%s.%N)
  # +WT1: single render thread => bit-reproducible; -A: no (deterministic) antialiasing jitter
  if ! "$POVRAY" +I"$SCENE" +L"$SCENEDIR" Declare=Pass="$pass" +W"$RES" +H"$RES" -A "$fmt" \
        +O"$tmp" -D +WT1 -GA -V >/dev/null 2>"$tmp.log"; then
    echo "FAILED pass $pass ($fmt):" >&2; cat "$tmp.log" >&2; exit 1
  fi
  [[ -s $tmp ]] || { echo "FAILED: $tmp is empty" >&2; cat "$tmp.log" >&2; exit 1; }
  mv -f "$tmp" "$out"; rm -f "$tmp.log"
  t1=$(date +%s.%N)
  wall=$(awk -v a="$t0" -v b="$t1" 'BEGIN{printf "%.3f", b-a}')
  if [[ $dolog == 1 ]]; then
    printf '%s\t%s\t1\t%s\t%s\n' "$(basename "$out")" "$pass" "${fmt#+F}" "$wall" >> "$LOG"
    printf 'render %-14s pass=%-5s %s wall=%ss\n' "$(basename "$out")" "$pass" "$fmt" "$wall"
  fi
}

have() { [[ -s $1 && ${FORCE:-0} != 1 ]] && echo "keep   $1 (exists)"; }

for (( k = 0; k < PASSES; k++ )); do
  f=$OUTDIR/$(printf 'pass_%02d.exr' "$k")
  have "$f" || pov "$f" "$k" +FE
done
if (( PASSES > 0 )); then
  have "$OUTDIR/pass_00.hdr" || pov "$OUTDIR/pass_00.hdr" 0 +FH
fi

if (( REF_PASSES > 0 )) && ! have "$OUTDIR/reference.exr"; then
  command -v oiiotool >/dev/null || { echo "reference needs oiiotool (openimageio-tools)" >&2; exit 1; }
  tmpd=$(mktemp -d)
  trap 'rm -rf "$tmpd"' EXIT
  t0=$(date +%s.%N)
  # running float32 sum, then divide by REF_PASSES
  for (( k = 0; k < REF_PASSES; k++ )); do
    pov "$tmpd/p.exr" $((1000 + k)) +FE 0
    if (( k == 0 )); then
      oiiotool --nosoftwareattrib "$tmpd/p.exr" -d float -o "$tmpd/sum.exr"
    else
      oiiotool --nosoftwareattrib "$tmpd/sum.exr" "$tmpd/p.exr" --add -d float -o "$tmpd/sum2.exr"
      mv -f "$tmpd/sum2.exr" "$tmpd/sum.exr"
    fi
  done
  oiiotool --nosoftwareattrib "$tmpd/sum.exr" --divc "$REF_PASSES" -d float --compression zip \
    --attrib proden:reference_passes "$REF_PASSES" --attrib proden:reference_first_pass 1000 \
    -o "$OUTDIR/reference.exr.partial.exr"
  mv -f "$OUTDIR/reference.exr.partial.exr" "$OUTDIR/reference.exr"
  t1=$(date +%s.%N)
  wall=$(awk -v a="$t0" -v b="$t1" 'BEGIN{printf "%.3f", b-a}')
  printf 'reference.exr\t1000..%d\t%d\tmean\t%s\n' $((999 + REF_PASSES)) "$REF_PASSES" "$wall" >> "$LOG"
  printf 'render reference.exr   mean of %d passes (1000..%d) wall=%ss\n' "$REF_PASSES" $((999 + REF_PASSES)) "$wall"
fi
