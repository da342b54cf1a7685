#!/usr/bin/env bash
# Actors behind network latency: HalfCheetah PPO end to end with the learner on this host and
# its actors in a network namespace whose link to the host delays every packet (tc netem, half
# the round trip each way), at round trips of 0, 5, 20 and 50 ms, beside the same run with the
# actors on loopback. Prints one table: env-steps/s (steady state, between the first and the
# last update), its ratio to loopback, the mean policy lag and the fragments dropped, with
# `rollouts_per_policy` 1 (each rollout waits for its update) and 2 (the next rollout is
# collected while the update and the network round trip happen).
#   sudo scripts/netem-bench.sh [ACTORS] [ENV_STEPS]      (defaults: 2 actors, 204800 steps)
# JSAE=path/to/jsae (default target/release/jsae). Needs root (ip netns, tc); prints
# "netem-bench: SKIPPED: why" and exits 0 where it cannot run. The namespace, its veth pair
# (10.78.0.1/24 on the host, 10.78.0.2 inside) and the run directories are removed at the
# end, also on failure. No traffic leaves the machine: the link exists only between the two.
# Where the kernel has no netem qdisc (a kernel without sch_netem, as on the Firecracker VMs
# this project's machines are), the actors stay on loopback and reach the learner through
# scripts/python/delay_proxy.py, which delays every chunk of the TCP stream by half the round
# trip each way (the table's `where` then says `proxy`).
set -euo pipefail
actors="${1:-2}"
steps="${2:-204800}"
jsae="$(realpath "${JSAE:-target/release/jsae}")"
ns=jsaenetem
host_if=jnetem0
ns_if=jnetem1
skip() { echo "netem-bench: SKIPPED: $*"; exit 0; }
[[ $(id -u) == 0 ]] || skip "not root (ip netns and tc need it)"
command -v tc >/dev/null || skip "no tc (Debian: iproute2)"
[[ -x "$jsae" ]] || skip "no $jsae (cargo build --release --bin jsae)"
ip netns add "$ns" 2>/dev/null || skip "ip netns add failed"
work="$(mktemp -d /tmp/jsae-netem.XXXXXX)"
pids=()
cleanup() {
    for p in "${pids[@]}"; do kill -KILL "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
    ip link del "$host_if" 2>/dev/null || true
    ip netns del "$ns" 2>/dev/null || true
    rm -rf "$work"
}
trap cleanup EXIT
ip link add "$host_if" type veth peer name "$ns_if"
ip link set "$ns_if" netns "$ns"
ip addr add 10.78.0.1/24 dev "$host_if"
ip link set "$host_if" up
ip netns exec "$ns" ip addr add 10.78.0.2/24 dev "$ns_if"
ip netns exec "$ns" ip link set "$ns_if" up
ip netns exec "$ns" ip link set lo up

# netem, or the userspace proxy where the kernel has no netem qdisc
mode=netns
if ! tc qdisc replace dev "$host_if" root netem delay 0ms 2>/dev/null; then
    mode=proxy
    echo "netem-bench: this kernel has no netem qdisc: the delay comes from scripts/python/delay_proxy.py" >&2
fi
proxy_rtt=0
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"

# the delay: half the round trip on each end of the link
delay() {
    if [[ $mode == proxy ]]; then
        proxy_rtt="$1"
        return
    fi
    local half
    half="$(python3 -c "print($1 / 2)")"
    tc qdisc replace dev "$host_if" root netem delay "${half}ms"
    ip netns exec "$ns" tc qdisc replace dev "$ns_if" root netem delay "${half}ms"
}

# steady-state env-steps/s, mean lag, dropped for lag, dropped for embedding (metrics.csv)
measure() {
    python3 - "$1/metrics.csv" <<'EOF'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
f = lambda r, k: float(r[k]) if r.get(k) not in (None, "") else 0.0
a, b = rows[0], rows[-1]
rate = (f(b, "env_steps") - f(a, "env_steps")) / max(f(b, "wall_seconds") - f(a, "wall_seconds"), 1e-9)
lag = sum(f(r, "policy_lag_mean") for r in rows) / len(rows)
print(f"{rate:.0f} {lag:.2f} {int(f(b, 'dropped_lag'))} {int(f(b, 'dropped_embedding'))}")
EOF
}

# one run: $1 = where the actors are (loopback | netns), $2 = rollouts_per_policy
run() {
    local where="$1" rollouts="$2" out="$work/run-$1-$2-$RANDOM"
    mkdir -p "$out"
    printf 'envs_per_actor = 16\nrollouts_per_policy = %s\neval_episodes = 1\n' "$rollouts" \
        >"$out/settings.toml"
    local common=(--env half-cheetah --algo ppo --seed 1 --config "$out/settings.toml")
    local addr=127.0.0.1
    [[ $where == netns ]] && addr=10.78.0.1
    "$jsae" learner --listen "$addr:0" "${common[@]}" --env-steps "$steps" --out "$out" \
        >"$out/learner.log" 2>&1 &
    local learner=$!
    pids+=("$learner")
    local url=""
    for _ in $(seq 100); do
        url="$(sed -n 's/^jsae-learner listening on \(.*\)$/http:\/\/\1/p' "$out/learner.log")"
        [[ -n $url ]] && break
        sleep 0.1
    done
    [[ -n $url ]] || { cat "$out/learner.log" >&2; echo "netem-bench: the learner did not start" >&2; exit 1; }
    if [[ $where == proxy ]]; then
        local port
        port="$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')"
        python3 "$here/python/delay_proxy.py" "$port" 127.0.0.1 "${url##*:}" "$proxy_rtt" \
            >"$out/proxy.log" 2>&1 &
        pids+=($!)
        for _ in $(seq 100); do grep -q ready "$out/proxy.log" && break; sleep 0.05; done
        url="http://127.0.0.1:$port"
    fi
    for id in $(seq 1 "$actors"); do
        if [[ $where == netns ]]; then
            ip netns exec "$ns" "$jsae" actor --learner "$url" "${common[@]}" --id "$id" \
                >"$out/actor-$id.log" 2>&1 &
        else
            "$jsae" actor --learner "$url" "${common[@]}" --id "$id" >"$out/actor-$id.log" 2>&1 &
        fi
        pids+=($!)
    done
    wait "$learner"
    measure "$out"
}

printf '%-9s %8s %9s %12s %10s %6s %8s %9s\n' where rtt_ms rollouts env-steps/s /loopback lag dropped dropped_e
for rollouts in 1 2; do
    run loopback "$rollouts" >"$work/result"
    read -r base lag dl de <"$work/result"
    printf '%-9s %8s %9s %12s %10s %6s %8s %9s\n' loopback - "$rollouts" "$base" 1.00 "$lag" "$dl" "$de"
    for rtt in 0 5 20 50; do
        delay "$rtt"
        run "$mode" "$rollouts" >"$work/result"
        read -r rate lag dl de <"$work/result"
        ratio="$(python3 -c "print(f'{$rate / max($base, 1):.2f}')")"
        printf '%-9s %8s %9s %12s %10s %6s %8s %9s\n' "$mode" "$rtt" "$rollouts" "$rate" "$ratio" "$lag" "$dl" "$de"
    done
done
echo "HalfCheetah PPO, $actors actors x 16 envs (the batch one rollout of every actor), $steps env steps a run; rtt: the round trip added between the actors and the learner ($mode: netns is tc netem on the namespace's link, proxy the delaying TCP proxy); env-steps/s between the first and the last update"
