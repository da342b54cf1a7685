#!/usr/bin/env bash
# deploy/docker-stack.yml on a real three-node Docker Swarm, on this machine (.ci/run runs it
# after the compose test; it says SKIPPED where it cannot run: no Docker, not root, no
# `ip netns`, no dockerd binary):
#  1. builds the jsae image on the host (deploy/build-images.sh) and saves it to a file;
#  2. makes its own network: the bridge jsaebr0 (10.77.0.1/24), three network namespaces
#     jsae-n1..3 on it through veths (10.77.0.11-13), and an iptables rule letting the bridge
#     forward (the host's Docker sets FORWARD to DROP); no route leads anywhere else;
#  3. starts one dockerd per namespace (its own UTS namespace, so hostnames n1..n3, data-root,
#     exec-root, pidfile, socket and cgroup-parent), n1 inits a swarm, n2 and n3 join as
#     workers, n1 is labelled jsae.state=true, and the image is loaded into every node;
#  4. creates the secret jsae_auth_token (a throw-away token) and the config jsae_config,
#     trains a small recommender run into the state node's volume, deploys the stack
#     (gridworld-discrete, JSAE, 3 actors) and checks the published ports from the host;
#  5. every node's actor contributes: the learner's Prometheus counters
#     jsae_learner_actor_env_steps{actor=SLOT} grow for each task slot, mapped to its node;
#  6. cuts the link of a worker (its host-side veth down): swarm marks the node Down, its actor
#     task is rescheduled on another node under the same slot, and the run goes on;
#  7. kills the learner: the restart policy starts a new container (a new address behind the
#     dnsrr name `learner`), it resumes from its checkpoint, and the actors reconnect by
#     themselves (no actor task is restarted);
#  8. the run completes: summary.json from the state node's volume; the actors exit 0; the
#     Recommender answers from the host with the token;
#  9. tears everything down, also on failure (trap): stack, swarm, daemons (by pidfile), their
#     mounts, cgroups and data, namespaces, veths, bridge, iptables rule, and checks so.
# Traffic goes only to the addresses this script creates (10.77.0.0/24, the namespaces and the
# swarm's overlay networks, 10.78.0.0/16) and to loopback: the nodes have no default route, the
# images are never resolved on a registry (--resolve-image never, and
# DOCKER_SERVICE_PREFER_OFFLINE_IMAGE=1 in the daemons' environment).
# PROFILE=dev uses the binaries the test suite built (CI); release by default.
# JSAE_ENV_STEPS sets the run's length (default 2,000,000: long enough that the cut and the
# restart fall mid-run, also on a loaded machine, where swarm took 45 s to mark a cut node
# Down and 1,000,000 steps ran out first).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
skip() { echo "swarm-test: SKIPPED: $*"; exit 0; }
command -v docker >/dev/null || skip "no docker client"
docker info >/dev/null 2>&1 || skip "no Docker engine answers (docker info failed)"
[[ "$(id -u)" == 0 ]] || skip "not root (it creates network namespaces and Docker daemons)"
command -v dockerd >/dev/null || skip "no dockerd binary to start the nodes with"
command -v ip >/dev/null && ip netns list >/dev/null 2>&1 || skip "no \`ip netns\` (iproute2)"
command -v nsenter >/dev/null && command -v unshare >/dev/null || skip "no nsenter/unshare"
command -v iptables >/dev/null || skip "no iptables"
iptables -L DOCKER-USER -n >/dev/null 2>&1 || skip "the host has no iptables chain DOCKER-USER"
docker stack --help >/dev/null 2>&1 || skip "this docker client has no \`docker stack\`"

t0=$(date +%s)
step() { echo "== swarm-test [$(($(date +%s) - t0)) s] $*"; }
# the script's stdout and stderr, kept on fds 8 and 9: a check that fails (or a signal that
# lands) inside wait_for, whose output goes to /dev/null, is still heard, and so is the teardown
exec 8>&1 9>&2
fail() { echo "swarm-test: FAILED: $*" >&9; exit 1; }
profile="${PROFILE:-release}"
bindir="${CARGO_TARGET_DIR:-$root/target}/$([[ $profile == release ]] && echo release || echo debug)"
image="jsae:latest"
stack=jsae
export JSAE_IMAGE="$image" JSAE_ENV=gridworld-discrete JSAE_ALGO=jsae JSAE_SEED=1
export JSAE_ENV_STEPS="${JSAE_ENV_STEPS:-2000000}" JSAE_RUN=gridworld
export JSAE_RECOMMENDER_RUN=recommender JSAE_ACTORS=3 RUST_LOG=info
export JSAE_CONFIG_NAME=jsae_config JSAE_AUTH_SECRET=jsae_auth_token JSAE_RECOMMENDER_REPLICAS=1
export JSAE_EMBEDDER_PORT=50051 JSAE_LEARNER_PORT=50052 JSAE_RECOMMENDER_PORT=50060
export JSAE_METRICS_LISTEN=0.0.0.0:9100
bridge=jsaebr0
net=10.77.0
nodes=(1 2 3)
host_veth() { echo "jsae-v$1"; }
netns() { echo "jsae-n$1"; }
exec_root() { echo "/run/jsae-swarm-n$1"; }
cgroup() { echo "jsae-swarm-n$1"; }
rule=(DOCKER-USER -i "$bridge" -o "$bridge" -j ACCEPT)
# names this script owns: if any is there, another run is going on (or one was killed
# before its teardown): stop, and touch none of them
for k in "${nodes[@]}"; do
    [[ ! -e "/run/netns/$(netns "$k")" ]] || fail "network namespace $(netns "$k") exists"
    [[ ! -e "$(exec_root "$k")" ]] || fail "$(exec_root "$k") exists"
    ! ip link show "$(host_veth "$k")" >/dev/null 2>&1 || fail "link $(host_veth "$k") exists"
done
! ip link show "$bridge" >/dev/null 2>&1 || fail "link $bridge exists"
! iptables -C "${rule[@]}" 2>/dev/null || fail "the iptables rule ${rule[*]} exists"

# the nodes' data-roots beside the host's, on a file system its storage driver works on
driver="$(docker info -f '{{.Driver}}')"
host_root="$(docker info -f '{{.DockerRootDir}}')"
work="$(mktemp -d "$(dirname "$host_root")/jsae-swarm.XXXXXX")"
chmod 755 "$work"
sock() { echo "$work/n$1/docker.sock"; }
D() { local k=$1; shift; docker -H "unix://$(sock "$k")" "$@"; }
made=() # what was made, in order, for the teardown to say what it removed

teardown() {
    local rc=$?
    set +e
    exec 1>&8 2>&9
    trap - INT TERM
    step "teardown (exit $rc)"
    if [[ $rc != 0 && -S "$(sock 1)" ]]; then
        timeout 10 docker -H "unix://$(sock 1)" node ls 2>&1
        timeout 10 docker -H "unix://$(sock 1)" stack ps --no-trunc "$stack" \
            --format '{{.Name}} {{.Node}} {{.DesiredState}} {{.CurrentState}} {{.Error}}' 2>&1 | head -30
        for s in embedder learner; do
            for c in $(timeout 10 docker -H "unix://$(sock 1)" ps -aq \
                --filter "label=com.docker.swarm.service.name=${stack}_$s" 2>/dev/null | head -2); do
                echo "--- $s container ${c:0:12} (n1), last lines:"
                timeout 10 docker -H "unix://$(sock 1)" logs --tail 15 "$c" 2>&1
            done
        done
    fi
    local removed=()
    if [[ -S "$(sock 1)" ]]; then
        local out
        out="$(timeout 30 docker -H "unix://$(sock 1)" stack rm "$stack" 2>&1)" \
            && removed+=("stack $stack") \
            || echo "stack rm $stack: $(tail -1 <<<"$out") (the daemons go anyway)"
    fi
    for k in "${nodes[@]}"; do
        [[ -S "$(sock "$k")" ]] || continue
        timeout 30 docker -H "unix://$(sock "$k")" swarm leave --force >/dev/null 2>&1 \
            && removed+=("n$k left the swarm")
    done
    step "teardown: stack removed, nodes left the swarm"
    # the daemons: SIGTERM by pidfile (each stops its containers and its containerd), SIGKILL
    # after 30 s; then their containerd where it survived
    local pids=() k pid
    for k in "${nodes[@]}"; do
        pid="$(cat "$work/n$k/dockerd.pid" 2>/dev/null)" || continue
        kill -TERM "$pid" 2>/dev/null && pids+=("$k:$pid")
    done
    for kp in "${pids[@]}"; do
        k=${kp%%:*} pid=${kp#*:}
        for _ in $(seq 60); do kill -0 "$pid" 2>/dev/null || break; sleep 0.5; done
        kill -0 "$pid" 2>/dev/null && { kill -KILL "$pid"; sleep 1; }
        pid="$(cat "$(exec_root "$k")/containerd/containerd.pid" 2>/dev/null)" \
            && kill -0 "$pid" 2>/dev/null && kill -KILL "$pid"
        removed+=("dockerd n$k (pid ${kp#*:})")
    done
    step "teardown: daemons stopped"
    # what a killed daemon left: processes in its containers' cgroups, mounts (deepest
    # first), the cgroups
    for k in "${nodes[@]}"; do
        find /sys/fs/cgroup/*/"$(cgroup "$k")" /sys/fs/cgroup/"$(cgroup "$k")" -name cgroup.procs \
            -exec cat {} + 2>/dev/null | sort -u | xargs -r kill -KILL 2>/dev/null
        grep -oE " ($work|$(exec_root "$k"))/[^ ]*" /proc/mounts | sort -r | while read -r m; do
            umount -l "$m" 2>/dev/null
        done
        for c in /sys/fs/cgroup/*/"$(cgroup "$k")" /sys/fs/cgroup/"$(cgroup "$k")"; do
            [[ -d "$c" ]] && find "$c" -depth -type d -exec rmdir {} + 2>/dev/null
        done
        [[ -e "$(exec_root "$k")" ]] && rm -rf --one-file-system "$(exec_root "$k")"
    done
    local thing
    for ((i = ${#made[@]} - 1; i >= 0; i--)); do
        thing="${made[i]}"
        case "$thing" in
            netns:*) ip netns del "${thing#netns:}" 2>/dev/null ;;
            link:*) ip link del "${thing#link:}" 2>/dev/null ;;
            iptables) iptables -D "${rule[@]}" 2>/dev/null ;;
        esac
        removed+=("$thing")
    done
    rm -rf --one-file-system "$work" && removed+=("$work")
    echo "swarm-test: removed: $(IFS=,; echo "${removed[*]}" | sed 's/,/, /g')"
    # nothing of ours may be left
    local left=()
    for k in "${nodes[@]}"; do
        [[ -e "/run/netns/$(netns "$k")" ]] && left+=("netns $(netns "$k")")
        ip link show "$(host_veth "$k")" >/dev/null 2>&1 && left+=("link $(host_veth "$k")")
        [[ -e "$(exec_root "$k")" ]] && left+=("$(exec_root "$k")")
        compgen -G "/sys/fs/cgroup/*/$(cgroup "$k")" >/dev/null && left+=("cgroup $(cgroup "$k")")
        [[ -e "/sys/fs/cgroup/$(cgroup "$k")" ]] && left+=("cgroup $(cgroup "$k")")
    done
    ip link show "$bridge" >/dev/null 2>&1 && left+=("link $bridge")
    iptables -C "${rule[@]}" 2>/dev/null && left+=("iptables rule")
    pgrep -f "dockerd --config-file $work/" >/dev/null && left+=("a dockerd")
    grep -qE " ($work|/run/jsae-swarm-n)" /proc/mounts && left+=("mounts")
    [[ -e "$work" ]] && left+=("$work")
    if [[ ${#left[@]} == 0 ]]; then
        echo "swarm-test: torn down: no daemon, namespace, link, iptables rule, mount or file left"
    else
        echo "swarm-test: left behind: ${left[*]}" >&2
        [[ $rc == 0 ]] && rc=1
    fi
    echo "swarm-test: $([[ $rc == 0 ]] && echo passed || echo FAILED) in $(($(date +%s) - t0)) s"
    exit "$rc"
}
trap teardown EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# wait_for SECONDS WHAT COMMAND...: polls the command every second until it succeeds
wait_for() {
    local secs=$1 what=$2
    shift 2
    for _ in $(seq "$secs"); do
        "$@" >/dev/null 2>&1 && return 0
        sleep 1
    done
    "$@" >/dev/null 2>&1 || fail "$what (waited $secs s)"
}

step "1. build the image (PROFILE=$profile) and save it"
PROFILE="$profile" TAG="$image" "$root/deploy/build-images.sh"
docker save "$image" >"$work/image.tar"
echo "image $image: $(($(stat -c %s "$work/image.tar") / 1000000)) MB saved"

# the rest must fit in 9 minutes (the build above is a no-op after the tests built)
deadline=$(($(date +%s) + 540))
step "2. the network: bridge $bridge ($net.1/24), namespaces and veths, the iptables rule"
ip link add "$bridge" type bridge
made+=("link:$bridge")
ip addr add "$net.1/24" dev "$bridge"
ip link set "$bridge" up
for k in "${nodes[@]}"; do
    ip netns add "$(netns "$k")"
    made+=("netns:$(netns "$k")")
    ip link add "$(host_veth "$k")" type veth peer name eth0 netns "$(netns "$k")"
    made+=("link:$(host_veth "$k")")
    ip link set "$(host_veth "$k")" master "$bridge" up
    ip -n "$(netns "$k")" addr add "$net.1$k/24" dev eth0
    ip -n "$(netns "$k")" link set eth0 up
    ip -n "$(netns "$k")" link set lo up
done
iptables -I "${rule[@]}"
made+=(iptables)

step "3. three dockerds ($driver), a swarm of n1 (manager) with n2, n3; the image in each"
for k in "${nodes[@]}"; do
    mkdir -p "$work/n$k"
    cat >"$work/n$k/daemon.json" <<EOF
{"data-root": "$work/n$k/data", "exec-root": "$(exec_root "$k")",
 "pidfile": "$work/n$k/dockerd.pid", "hosts": ["unix://$(sock "$k")"],
 "cgroup-parent": "/$(cgroup "$k")", "storage-driver": "$driver", "mtu": 1400,
 "shutdown-timeout": 5, "log-driver": "json-file", "log-opts": {"max-size": "10m"}}
EOF
    # `ip netns exec` would remount /sys, and dockerd then finds no devices cgroup; a UTS
    # namespace gives each node its own hostname (the swarm's node name)
    nsenter --net="/run/netns/$(netns "$k")" unshare --uts --fork sh -c \
        "hostname n$k; exec env DOCKER_SERVICE_PREFER_OFFLINE_IMAGE=1 dockerd --config-file $work/n$k/daemon.json" \
        >"$work/n$k/dockerd.log" 2>&1 8>&- 9>&- &
done
for k in "${nodes[@]}"; do
    wait_for 60 "dockerd n$k did not answer on $(sock "$k"), see $work/n$k/dockerd.log" D "$k" info
done
# heartbeats every 2 s (5 s by default): a lost node is marked Down sooner
D 1 swarm init --advertise-addr "$net.11" --listen-addr "$net.11:2377" --dispatcher-heartbeat 2s \
    --default-addr-pool 10.78.0.0/16 --default-addr-pool-mask-length 24 >/dev/null
join_token="$(D 1 swarm join-token -q worker)"
for k in 2 3; do
    D "$k" swarm join --token "$join_token" --advertise-addr "$net.1$k" \
        --listen-addr "$net.1$k:2377" "$net.11:2377" >/dev/null
done
D 1 node update --label-add jsae.state=true n1 >/dev/null
loads=()
for k in "${nodes[@]}"; do
    D "$k" load -q -i "$work/image.tar" >/dev/null &
    loads+=($!)
done
for k in "${nodes[@]}"; do
    wait "${loads[k - 1]}" || fail "docker load into n$k failed"
done
rm -f "$work/image.tar"
D 1 node ls
echo "n1 labels: $(D 1 node inspect -f '{{json .Spec.Labels}}' n1); $image loaded on n1, n2, n3"

step "4. secret, config, a recommender run on n1; deploy the stack (3 actors)"
head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' >"$work/token"
cat >"$work/config.toml" <<'EOF'
actors = 3
envs_per_actor = 8
rollout_len = 64
eval_episodes = 5
[embedding]
pretrain_transitions = 4096
pretrain_per_action = 0
pretrain_epochs = 3
[ppo]
epochs = 4
EOF
chmod 644 "$work/config.toml"
D 1 secret create "$JSAE_AUTH_SECRET" "$work/token" >/dev/null
D 1 config create "$JSAE_CONFIG_NAME" "$work/config.toml" >/dev/null
# the Recommender's run, in the volume the stack's services use on n1 (<stack>_runs)
D 1 run --rm --network none -v "${stack}_runs:/runs" -v "$work/config.toml:/etc/jsae/config.toml:ro" \
    "$image" train --config /etc/jsae/config.toml --env recommender --algo ppo --one-process \
    --env-steps 4096 --eval-episodes 5 --quiet --out /runs/recommender >/dev/null
D 1 stack deploy --resolve-image never -c "$root/deploy/docker-stack.yml" "$stack"
container() { # NODE SERVICE: the running container of a service on a node
    D "$1" ps -q --filter "label=com.docker.swarm.service.name=${stack}_$2" --filter status=running | head -1
}
healthy() { [[ "$(D 1 inspect -f '{{.State.Health.Status}}' "$(container 1 "$1")")" == healthy ]]; }
serving() { "$bindir/jsae" health --addr "$net.11:$1" --service "$2" --timeout-ms 500; }
for s in "embedder 50051 jsae.v1.Embedder" "learner 50052 jsae.v1.Learner" \
    "recommender 50060 jsae.v1.Recommender"; do
    set -- $s
    wait_for 120 "$1 is not healthy on n1" healthy "$1"
    wait_for 10 "$1 is not SERVING on $net.11:$2 (its host-mode port)" serving "$2" "$3"
    echo "$1: healthy on n1, SERVING on $net.11:$2 (host mode) after $(($(date +%s) - t0)) s"
done
actor_tasks() { # running actor tasks: SLOT NODE TASK_ID
    D 1 service ps --no-trunc "${stack}_actor" --filter desired-state=running \
        --format '{{.Name}} {{.Node}} {{.ID}} {{.CurrentState}}' |
        awk '$4 == "Running" { sub(/.*\./, "", $1); print $1, $2, $3 }' | sort -n
}
spread() { [[ "$(actor_tasks | awk '{print $2}' | sort -u | tr '\n' ' ')" == "n1 n2 n3 " ]]; }
wait_for 60 "the 3 actors are not running one per node" spread

# the learner's Prometheus text, read in its container (its port 9100 is not published; the
# image has bash, whose /dev/tcp speaks enough HTTP)
scrape() {
    local c
    c="$(container 1 learner)"
    [[ -n "$c" ]] || return 1
    D 1 exec "$c" bash -c 'exec 3<>/dev/tcp/127.0.0.1/9100 &&
        printf "GET /metrics HTTP/1.0\r\nHost: learner\r\n\r\n" >&3 && cat <&3' 2>/dev/null
}
metric() { # NAME{LABELS} in the last scrape ($m): its value, 0 when absent
    awk -v n="$1" '$1 == n { v = $2 } END { printf "%d\n", v + 0 }' <<<"$m"
}
steps_of() { # SLOT: env steps the learner received from that actor id
    awk -v a="actor=\"$1\"" '$1 ~ /^jsae_learner_actor_env_steps(_total)?\{/ && index($1, a) { v = $2 }
        END { printf "%d\n", v + 0 }' <<<"$m"
}
all_steps() { metric jsae_learner_env_steps; }
# the checks below need the run going on: stop at once where it has ended
ended_early() {
    [[ -z "$(D 1 ps -aq --filter "label=com.docker.swarm.service.name=${stack}_learner" \
        --filter exited=0)" ]] || fail "the run ended too early (JSAE_ENV_STEPS=$JSAE_ENV_STEPS): raise it"
}
# every actor in `slots` has sent steps (more than floor[SLOT] where that is set)
declare -A floor
all_contribute() {
    ended_early
    m="$(scrape)" || return 1
    local s
    for s in $slots; do
        [[ $(steps_of "$s") -gt ${floor[$s]:-0} ]] || return 1
    done
}

step "5. every node's actor sends fragments (jsae_learner_actor_env_steps by slot)"
slots="$(actor_tasks | awk '{print $1}' | tr '\n' ' ')"
wait_for 180 "not every actor's env steps reached the learner" all_contribute
m="$(scrape)"
echo "jsae_learner_actors: connected $(metric 'jsae_learner_actors{state="connected"}'), present $(metric 'jsae_learner_actors{state="present"}'); env steps $(all_steps) of $JSAE_ENV_STEPS"
while read -r slot node _; do
    echo "actor slot $slot on $node: $(steps_of "$slot") env steps at the learner"
done < <(actor_tasks)
[[ $(metric 'jsae_learner_actors{state="connected"}') == 3 ]] || fail "the learner does not see 3 actors"

step "6. cut a worker's link; its actor moves to another node; the run goes on"
read -r moved cut_node cut_task < <(actor_tasks | awk '$2 != "n1"' | tail -1)
k=${cut_node#n}
steps_at_cut=$(all_steps)
moved_at_cut=$(steps_of "$moved")
ip link set "$(host_veth "$k")" down
cut_at=$(date +%s)
echo "link $(host_veth "$k") of $cut_node down (actor slot $moved, task ${cut_task:0:12}) at $steps_at_cut env steps"
node_down() { [[ "$(D 1 node inspect -f '{{.Status.State}}' "$cut_node")" == down ]]; }
wait_for 90 "swarm did not mark $cut_node Down" node_down
echo "$cut_node is Down after $(($(date +%s) - cut_at)) s"
rescheduled() { actor_tasks | awk -v s="$moved" -v n="$cut_node" '$1 == s && $2 != n { f = 1 } END { exit !f }'; }
wait_for 90 "actor slot $moved was not rescheduled off $cut_node" rescheduled
read -r _ new_node new_task < <(actor_tasks | awk -v s="$moved" '$1 == s')
echo "actor slot $moved rescheduled on $new_node (task ${new_task:0:12}) after $(($(date +%s) - cut_at)) s"
floor=([$moved]=$moved_at_cut)
wait_for 120 "actor slot $moved did not send again from $new_node" all_contribute
[[ $(all_steps) -gt $steps_at_cut ]] || fail "the learner's env steps did not rise after the cut"
echo "the run goes on: env steps $steps_at_cut -> $(all_steps); slot $moved $moved_at_cut -> $(steps_of "$moved") (now from $new_node)"
[[ $(all_steps) -lt $JSAE_ENV_STEPS ]] || fail "the run ended before the learner's restart: raise JSAE_ENV_STEPS"

step "7. kill the learner; swarm restarts it; it resumes and the actors reconnect"
tasks_before="$(actor_tasks | awk '{print $3}' | sort | tr '\n' ' ')"
old_learner="$(container 1 learner)"
ip_of() { D 1 inspect -f '{{range .NetworkSettings.Networks}}{{.IPAddress}} {{end}}' "$1" | xargs; }
old_ip="$(ip_of "$old_learner")"
steps_at_kill=$(all_steps)
killed_at="$(date -u +%Y-%m-%dT%H:%M:%SZ)"
D 1 kill "$old_learner" >/dev/null
echo "killed the learner's container ${old_learner:0:12} (overlay address $old_ip) at $steps_at_kill env steps"
restarted() { local c; c="$(container 1 learner)"; [[ -n "$c" && "$c" != "$old_learner" ]]; }
wait_for 60 "swarm did not start a new learner" restarted
learner="$(container 1 learner)"
resumed() { D 1 logs "$learner" 2>&1 | grep -q "resuming from the policy checkpoint"; }
wait_for 60 "the new learner did not resume from its checkpoint" resumed
D 1 logs "$learner" 2>&1 | grep -E "resuming from the policy checkpoint|the run goes on from" | sed 's/^/  /'
echo "new learner container ${learner:0:12} (task $(D 1 inspect -f '{{index .Config.Labels "com.docker.swarm.task.id"}}' "$learner" | cut -c1-12), overlay address $(ip_of "$learner"))"
floor=()
connected3() { all_contribute && [[ $(metric 'jsae_learner_actors{state="connected"}') == 3 ]] \
    && [[ $(all_steps) -gt $steps_at_kill ]]; }
wait_for 120 "the actors did not all reconnect to the new learner" connected3
echo "actors reconnected: connected $(metric 'jsae_learner_actors{state="connected"}'); env steps $steps_at_kill -> $(all_steps); by slot: $(for s in $slots; do printf '%s=%s ' "$s" "$(steps_of "$s")"; done)"
[[ "$(actor_tasks | awk '{print $3}' | sort | tr '\n' ' ')" == "$tasks_before" ]] \
    || fail "an actor task was restarted (tasks before: $tasks_before)"
echo "no actor task was restarted; what they logged about the learner since the kill:"
while read -r slot node task; do
    c="$(D "${node#n}" ps -q --filter "label=com.docker.swarm.task.id=$task")"
    D "${node#n}" logs --since "$killed_at" "$c" 2>&1 | grep -iE "learner|policy stream" | tail -3 \
        | sed "s/^/  slot $slot on $node: /"
done < <(actor_tasks)

step "8. the run completes; summary.json from n1's volume; the Recommender answers"
finished() { [[ "$(D 1 inspect -f '{{.State.Status}}' "$learner")" == exited ]]; }
wait_for $((deadline - $(date +%s))) "the run did not finish in time" finished
[[ "$(D 1 inspect -f '{{.State.ExitCode}}' "$learner")" == 0 ]] || fail "the learner did not exit 0"
echo "learner exited 0 after $(($(date +%s) - t0)) s; task $(D 1 service ps "${stack}_learner" --format '{{.CurrentState}}' | head -1)"
summary="$(D 1 run --rm --network none -v "${stack}_runs:/runs" --entrypoint cat "$image" \
    "/runs/$JSAE_RUN/summary.json")"
python3 - "$summary" "$JSAE_ENV_STEPS" <<'PY'
import json, sys
s = json.loads(sys.argv[1])
keys = ["env", "algo", "env_steps", "learner_updates", "policy_version", "embedding_version",
        "wall_seconds", "steps_per_second", "eval_return_mean"]
print("summary.json:", json.dumps({k: s.get(k) for k in keys}))
assert s["env"] == "gridworld-discrete" and s["env_steps"] >= int(sys.argv[2]), s
assert s["learner_updates"] > 0 and s["embedding_version"] >= 1, s
PY
# the actor tasks end Complete (exit 0), each on its node; the moved one says it stepped
for task in $tasks_before; do
    done_ok() { [[ "$(D 1 inspect --type task -f '{{.Status.State}}' "$task")" == complete ]]; }
    wait_for 60 "actor task ${task:0:12} did not complete" done_ok
done
c="$(D "${new_node#n}" ps -aq --filter "label=com.docker.swarm.task.id=$new_task" | head -1)"
D "${new_node#n}" logs "$c" 2>&1 | grep -E "Finished after [1-9][0-9]* env steps" \
    | sed "s/^/  slot $moved on $new_node: /" \
    || fail "the moved actor (slot $moved on $new_node) did not finish having stepped"
echo "the actors' tasks completed (exit 0)"
answer="$("$bindir/jsae" recommend --auth-token-file "$work/token" --addr "$net.11:50060" --k 3 24852 13176)"
echo "Recommend via $net.11:50060: $answer"
python3 -c 'import json, sys; a = json.loads(sys.argv[1]); assert len(a["items"]) == 3, a' "$answer"

step "9. passed; tearing down"
