#!/usr/bin/env bash
# Generate the learned mixer's validation and training data (resumable: rerun to continue).
#
#   training/generate.sh                       # 8 val frames, then TRAIN_COUNT train frames
#   nohup training/generate.sh > /work/trainingdata/generate.log 2>&1 &
#
# Environment: VAL_COUNT (8), TRAIN_COUNT (64), TRAIN_START (0), DEADLINE_MIN (45: start no
# new train frame after this many minutes; 0 = no limit), TRAINING_DATA (/work/trainingdata),
# BLENDER, PRODEN (default build/proden, from `make build`), DENOISER (the inputs' denoiser,
# `proden denoise --denoiser`; default proden's).
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
VAL_COUNT=${VAL_COUNT:-8}
TRAIN_COUNT=${TRAIN_COUNT:-64}
TRAIN_START=${TRAIN_START:-0}
DEADLINE_MIN=${DEADLINE_MIN:-45}
DEADLINE=0
if (( DEADLINE_MIN > 0 )); then DEADLINE=$(( $(date +%s) + DEADLINE_MIN * 60 )); fi
echo "generate.sh: start $(date -Is) val=$VAL_COUNT train=$TRAIN_COUNT from $TRAIN_START deadline=$DEADLINE"
/usr/bin/python3 "$HERE/render_set.py" --split val --count "$VAL_COUNT" --start 0
/usr/bin/python3 "$HERE/render_set.py" --split train --count "$TRAIN_COUNT" --start "$TRAIN_START" \
  --deadline "$DEADLINE"
echo "generate.sh: done $(date -Is)"
