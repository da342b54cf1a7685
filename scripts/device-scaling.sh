#!/usr/bin/env bash
# The many-core measurements of issue 42 in one script, for a machine with many cores (the
# numbers in docs/src/performance/scaling.md came from it): the actor ladder (`jsae bench --scaling`),
# HalfCheetah PPO 1M with 1 and 4 actors over 5 seeds (and with 4 and 8 actors keeping 32
# minibatches), and the separate-process gridworld sweeps with 2 and 4 actors. Everything goes
# under OUT (default runs/device); each part, once done, into its own tarball in PACK (default
# OUT's folder), so a part cut short by a time limit leaves the earlier ones whole; `jsae
# report` the sweep folders afterwards, where a font is installed.
#   JSAE=path/to/jsae [PACK=dir] [LADDER=1,2,4,8] [QUICK=1] scripts/device-scaling.sh [OUT] [PARTS]
# PARTS: any of ladder, cheetah, minibatches, minibatches-lr, sweep, byhand (default: ladder,
# cheetah, sweep and byhand).
# byhand: ten runs of scripts/by-hand-run.sh (2 actors, one killed with SIGKILL and
# replaced), five at a time.
set -uo pipefail
out="${1:-runs/device}"
parts="${2:-ladder cheetah sweep byhand}"
jsae="${JSAE:-target/release/jsae}"
pack_dir="${PACK:-$(dirname "$out")}"
mkdir -p "$out" "$pack_dir"
has() { [[ " $parts " == *" $1 "* ]]; }
log() { echo "[$(date +%T)] $*" | tee -a "$out/device.log"; }
# a part's files without checkpoints and recordings (small enough to bring back), and the log
pack() {
    tar --exclude='*.ckpt' --exclude='*.mcap' --exclude='checkpoints' \
        -czf "$pack_dir/$1.tar.gz" -C "$out" device.log "${@:2}"
    log "packed $1: $(du -h "$pack_dir/$1.tar.gz" | cut -f1)"
}
log "cores $(nproc), $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2)"
if has ladder; then
    log "ladder"
    # QUICK=1: the bench's short runs (a check of this script on a small machine)
    "$jsae" bench --scaling --actors "${LADDER:-1,2,4,8}" ${QUICK:+--quick} \
        >"$out/scaling.txt" 2>"$out/scaling.err"
    cat "$out/scaling.txt" | tee -a "$out/device.log"
    pack ladder scaling.txt scaling.err
fi
if has cheetah; then
    log "half-cheetah 1M, 1 and 4 actors, 5 seeds"
    "$jsae" sweep results/sweeps/half-cheetah-actors.toml --jobs 3 --out "$out/half-cheetah-actors" \
        >"$out/half-cheetah-actors.log" 2>&1
    log "half-cheetah done"
    pack cheetah half-cheetah-actors half-cheetah-actors.log
fi
if has minibatches; then
    log "half-cheetah 1M, 1 actor, and 4 and 8 actors with ppo.minibatches = 32, 5 seeds"
    "$jsae" sweep results/sweeps/half-cheetah-actors-minibatches.toml --jobs 4 \
        --out "$out/half-cheetah-actors-minibatches" >"$out/half-cheetah-actors-minibatches.log" 2>&1
    log "half-cheetah minibatches done"
    pack minibatches half-cheetah-actors-minibatches half-cheetah-actors-minibatches.log
fi
if has minibatches-lr; then
    log "half-cheetah 1M, 4 and 8 actors with ppo.minibatches = 32 and the lr scaled, 5 seeds"
    "$jsae" sweep results/sweeps/half-cheetah-actors-minibatches-lr.toml --jobs 4 \
        --out "$out/half-cheetah-actors-minibatches-lr" \
        >"$out/half-cheetah-actors-minibatches-lr.log" 2>&1
    log "half-cheetah minibatches-lr done"
    pack minibatches-lr half-cheetah-actors-minibatches-lr half-cheetah-actors-minibatches-lr.log
fi
if has sweep; then
    log "gridworld separate processes, 2 and 4 actors, 10 seeds"
    "$jsae" sweep results/sweeps/gridworld-services-actors.toml --jobs 4 \
        --out "$out/gridworld-services-actors" >"$out/gridworld-services-actors.log" 2>&1
    log "gridworld done"
    pack sweep gridworld-services-actors gridworld-services-actors.log
fi
if has byhand; then
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
    pack byhand by-hand by-hand.jsonl
fi
