#!/usr/bin/env bash
# `make run`: starts `proden serve` on 127.0.0.1:${PORT:-8080} with the built-in default config,
# a state dir under out/daemon/, and a demo shot of six frames fed by the committed passes
# (odd frames the Cornell box, even frames textured_dof; frame f's k-th pass is sample
# (f + k) mod 8), one pass a second round-robin over the frames, so every frame improves every
# few seconds on the dashboard. Prints the dashboard's URL; runs until Ctrl-C (SIGINT drains and
# persists state).
set -euo pipefail
BIN=${BIN:-build/proden}
PORT=${PORT:-8080}
OUT=${OUT_DIR:-out}/daemon
FRAMES=${FRAMES:-6}
mkdir -p "$OUT/state" "$OUT/root/watch" "$OUT/root/out"
ROOT=$(cd "$OUT/root" && pwd)

"$BIN" serve --port "$PORT" --state-dir "$OUT/state" --allow-root "$ROOT" > "$OUT/stdout.log" &
DAEMON=$!
trap 'kill -TERM $DAEMON 2>/dev/null; wait $DAEMON 2>/dev/null || true; exit 0' INT TERM
for _ in $(seq 100); do
  grep -q "listening on" "$OUT/stdout.log" 2>/dev/null && break
  kill -0 $DAEMON 2>/dev/null || { echo "proden serve failed to start" >&2; exit 1; }
  sleep 0.1
done
URL=$(sed -n 's/^listening on //p' "$OUT/stdout.log")
curl -s -X POST "$URL/api/v1/jobs" -H 'Content-Type: application/json' -d "{
  \"name\": \"demo_shot\", \"renderer\": \"cycles\",
  \"watch\": {\"dir\": \"$ROOT/watch\", \"pattern\": \"pass_{pass}/beauty_####.exr\"},
  \"output\": {\"dir\": \"$ROOT/out\", \"formats\": [\"exr\", \"png\"]}}" > /dev/null || true
JOB=$(curl -s "$URL/api/v1/jobs" | sed -n 's/.*"id":"\([^"]*\)".*"name":"demo_shot".*/\1/p')
echo
echo "proden serve: dashboard at $URL/#/job/$JOB"
echo "  (demo_shot = job $JOB, $FRAMES frames, outputs in $ROOT/out)"
echo "  curl -N $URL/api/v1/events"
echo "  curl $URL/api/v1/jobs/$JOB/frames"
echo "  $URL/api/v1/jobs/$JOB/frames/1/image?format=png"
echo "Ctrl-C stops the daemon."
(
  for k in 0 1 2 3 4 5 6 7; do
    for f in $(seq "$FRAMES"); do
      scene=cornell; [ $((f % 2)) -eq 0 ] && scene=textured_dof
      src=$(printf 'samples/renders/%s/pass_%02d.exr' "$scene" $(((f + k) % 8)))
      dst=$(printf '%s/watch/pass_%02d/beauty_%04d.exr' "$ROOT" "$k" "$f")
      [ -e "$dst" ] && continue
      mkdir -p "$(dirname "$dst")"
      cp "$src" "$dst.tmp" && mv "$dst.tmp" "$dst"
      sleep 1
    done
  done
) &
wait $DAEMON
