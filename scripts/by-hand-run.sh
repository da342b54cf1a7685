#!/usr/bin/env bash
# One run launched by hand as docs/src/operations/services.md describes: the embedder,
# the learner and two actors as separate processes on loopback, nothing telling the learner
# how many actors there are; one actor is killed with SIGKILL 10-15 s in and a replacement
# (a new id) started. Prints the run's summary.json on one line, prefixed with the seed.
#   scripts/by-hand-run.sh SEED OUT_DIR [ENV_STEPS]
# JSAE=path/to/jsae (default target/release/jsae); the run's settings are the defaults of
# gridworld-discrete with JSAE (512 actions), or CONFIG=settings.toml's (given to every process).
# Ports are free ones, so runs can go side by side.
set -euo pipefail
seed="$1"
out="$2"
steps="${3:-500000}"
jsae="${JSAE:-target/release/jsae}"
common=(--env gridworld-discrete --algo jsae --seed "$seed")
if [[ -n "${CONFIG:-}" ]]; then
    common+=(--config "$CONFIG")
fi
rm -rf "$out"
mkdir -p "$out/logs"
read -r eport lport < <(python3 -c '
import socket
held = [socket.socket() for _ in range(2)]
for s in held:
    s.bind(("127.0.0.1", 0))
print(*(s.getsockname()[1] for s in held))')
pids=()
cleanup() {
    for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
}
trap cleanup EXIT
"$jsae" embedder --listen "127.0.0.1:$eport" "${common[@]}" \
    --checkpoint-dir "$out/checkpoints" >"$out/logs/embedder.log" 2>&1 &
pids+=($!)
"$jsae" learner --listen "127.0.0.1:$lport" --embedder "http://127.0.0.1:$eport" "${common[@]}" \
    --env-steps "$steps" --out "$out" >"$out/logs/learner.log" 2>&1 &
learner=$!
pids+=($learner)
actor() {
    "$jsae" actor --embedder "http://127.0.0.1:$eport" --learner "http://127.0.0.1:$lport" \
        "${common[@]}" --id "$1" >"$out/logs/actor-$1.log" 2>&1 &
    pids+=($!)
}
actor 0
actor 1
victim=${pids[-1]}
sleep "$((10 + seed % 6))"
kill -KILL "$victim" 2>/dev/null || true
actor 2
wait "$learner"
echo "$seed $(python3 -c 'import json,sys; print(json.dumps(json.load(open(sys.argv[1]))))' "$out/summary.json")"
