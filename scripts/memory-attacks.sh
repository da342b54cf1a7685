#!/usr/bin/env bash
# Issue 43's memory attacks against the services of a real run (separate processes on
# loopback), with each service's peak RSS (VmHWM) after each attack and a health check every
# 200 ms throughout (tests/examples/memory_attacks.rs). Exits 1 if a peak passes 512 MB or a
# check went unanswered. Release build:
#   cargo build --release -p jsae-cli && cargo build --release -p jsae-tests --example memory_attacks
#   scripts/memory-attacks.sh [ENV] [ALGO]        (default: gridworld-discrete jsae)
set -euo pipefail
cd "$(dirname "$0")/.."
jsae="${JSAE:-target/release/jsae}"
attack="${ATTACK:-target/release/examples/memory_attacks}"
env="${1:-gridworld-discrete}"
algo="${2:-jsae}"
work="$(mktemp -d)"
"$jsae" train --env "$env" --algo "$algo" --env-steps 100000000 --out "$work/run" \
    >"$work/train.log" 2>&1 &
train=$!
cleanup() {
    kill -TERM "$train" 2>/dev/null || true
    wait "$train" 2>/dev/null || true
    rm -rf "$work"
}
trap cleanup EXIT
url() { grep -o "$1 on http://[0-9.:]*" "$work/train.log" | head -1 | cut -d' ' -f3; }
for _ in $(seq 1 120); do
    [[ -n "$(url learner)" ]] && break
    sleep 0.5
done
learner="$(url learner)"
embedder="$(url embedder)"
[[ -n "$learner" && -n "$embedder" ]] || { echo "the run did not start: $(tail -3 "$work/train.log")"; exit 2; }
pid() { pgrep -f "jsae $1 .*$work/" | head -1; }
# let the embedder publish its first snapshot and the learner a few updates
sleep 10
echo "$env $algo: learner $learner (pid $(pid learner)), embedder $embedder (pid $(pid embedder))"
"$attack" "$learner" "$embedder" "$(pid learner)" "$(pid embedder)"
