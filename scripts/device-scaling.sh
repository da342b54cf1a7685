#!/usr/bin/env bash
# The many-core measurements of issue 42 in one script, for a machine with many cores (the
# numbers in README "Scaling out" came from it): the actor ladder (`jsae bench --scaling`),
# HalfCheetah PPO 1M with 1 and 4 actors over 5 seeds, and the separate-process gridworld
# sweeps with 2 and 4 actors. Everything goes under OUT (default runs/device) and into one
# tarball, OUT.tar.gz; `jsae report` the sweep folders afterwards, where a font is installed.
#   JSAE=path/to/jsae scripts/device-scaling.sh [OUT] [PARTS]
# PARTS: any of ladder, cheetah, sweep, byhand (default: all four). byhand: ten runs of
# scripts/by-hand-run.sh (2 actors, one killed with SIGKILL and replaced), five at a time.
set -uo pipefail
out="${1:-runs/device}"
parts="${2:-ladder cheetah sweep byhand}"
jsae="${JSAE:-target/release/jsae}"
mkdir -p "$out"
log() { echo "[$(date +%T)] $*" | tee -a "$out/device.log"; }
log "cores $(nproc), $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2)"
if [[ $parts == *ladder* ]]; then
    log "ladder"
    "$jsae" bench --scaling --actors 1,2,4,8 >"$out/scaling.txt" 2>"$out/scaling.err"
    cat "$out/scaling.txt" | tee -a "$out/device.log"
fi
if [[ $parts == *cheetah* ]]; then
    log "half-cheetah 1M, 1 and 4 actors, 5 seeds"
    "$jsae" sweep results/sweeps/half-cheetah-actors.toml --jobs 3 --out "$out/half-cheetah-actors" \
        >"$out/half-cheetah-actors.log" 2>&1
    log "half-cheetah done"
fi
if [[ $parts == *sweep* ]]; then
    log "gridworld separate processes, 2 and 4 actors, 10 seeds"
    "$jsae" sweep results/sweeps/gridworld-services-actors.toml --jobs 4 \
        --out "$out/gridworld-services-actors" >"$out/gridworld-services-actors.log" 2>&1
    log "gridworld done"
fi
if [[ $parts == *byhand* ]]; then
    log "by hand: 2 actors, one killed and replaced, 10 seeds"
    for wave in 2001 2006; do
        for seed in $(seq "$wave" $((wave + 4))); do
            JSAE="$jsae" scripts/by-hand-run.sh "$seed" "$out/by-hand/seed$seed" \
                >"$out/by-hand-$seed.out" 2>&1 &
        done
        wait
    done
    cat "$out"/by-hand-*.out | grep '^[0-9]' >"$out/by-hand.jsonl" || true
    log "by hand done: $(wc -l <"$out/by-hand.jsonl") summaries"
fi
# the run directories without their checkpoints and recordings (small enough to bring back)
tar --exclude='*.ckpt' --exclude='*.mcap' --exclude='checkpoints' -czf "$out.tar.gz" "$out"
log "tarball $(du -h "$out.tar.gz" | cut -f1)"
