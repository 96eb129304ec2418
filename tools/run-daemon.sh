#!/usr/bin/env bash
# `make run`: starts `proden serve` on 127.0.0.1:${PORT:-8080} with the built-in default config,
# a state dir under out/daemon/, and a demo job fed by the committed Cornell passes arriving one
# by one (every 3 s). Prints the URL; runs until Ctrl-C (SIGINT drains and persists state).
set -euo pipefail
BIN=${BIN:-build/proden}
PORT=${PORT:-8080}
OUT=${OUT_DIR:-out}/daemon
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
  \"name\": \"cornell\", \"renderer\": \"cycles\",
  \"watch\": {\"dir\": \"$ROOT/watch\", \"pattern\": \"pass_{pass}/beauty_####.exr\"},
  \"output\": {\"dir\": \"$ROOT/out\", \"formats\": [\"exr\", \"png\"]}}" > /dev/null || true
JOB=$(curl -s "$URL/api/v1/jobs" | sed -n 's/.*"id":"\([^"]*\)".*"name":"cornell".*/\1/p')
echo
echo "proden serve: $URL  (job cornell = $JOB, outputs in $ROOT/out)"
echo "  curl -N $URL/api/v1/events"
echo "  curl $URL/api/v1/jobs/$JOB/frames"
echo "  $URL/api/v1/jobs/$JOB/frames/1/image?format=png"
echo "Ctrl-C stops the daemon."
(
  for f in samples/renders/cornell/pass_0*.exr; do
    n=$(basename "$f" .exr | sed 's/pass_//')
    dst="$ROOT/watch/pass_$n/beauty_0001.exr"
    [ -e "$dst" ] && continue
    mkdir -p "$(dirname "$dst")"
    cp "$f" "$dst.tmp" && mv "$dst.tmp" "$dst"
    sleep 3
  done
) &
wait $DAEMON
