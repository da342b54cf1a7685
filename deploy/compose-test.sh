#!/usr/bin/env bash
# The docker compose stack, tested for real (.ci/run runs it when a Docker engine answers),
# with the shared bearer token (a throw-away one unless JSAE_HOST_TOKEN_FILE names one):
#  1. builds the base image (debootstrap, no registry) and the jsae image from this checkout;
#  2. trains a small recommender run into the volume with the one-off `train` service;
#  3. starts the embedder, the learner, 2 actors and the recommender, and times each to
#     SERVING (gRPC health from the host, which needs no token);
#  4. kills one actor mid-run (docker kill); --scale brings up a replacement, which joins;
#  5. restarts the learner: it resumes from its checkpoint and the actors reconnect by
#     themselves (none of them is restarted);
#  6. the run completes: summary.json is read from the volume;
#  7. the recommender answers a Recommend call from the host with the token; in its container
#     a call without the token is refused (Unauthenticated) and one with the mounted secret
#     /run/secrets/jsae_auth_token is answered;
#  8. tears everything down (containers, network, volume), also on failure, and checks so.
# PROFILE=dev uses the binaries the test suite built (CI); release by default.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if ! docker info >/dev/null 2>&1; then
    echo "compose-test: SKIPPED: no Docker engine answers (docker info failed)"
    exit 0
fi
t0=$(date +%s)
step() { echo "== compose-test [$(($(date +%s) - t0)) s] $*"; }
fail() { echo "compose-test: FAILED: $*" >&2; exit 1; }

profile="${PROFILE:-release}"
bindir="$root/target/$([[ $profile == release ]] && echo release || echo debug)"
export COMPOSE_PROJECT_NAME="jsaetest$$"
export JSAE_IMAGE="jsae:latest"
# 2M steps so that the kill (4) and the restart (5) fall mid-run: 600k ended about 30 s after
# the stack came up, before the restart
export JSAE_ENV=gridworld-discrete JSAE_ALGO=jsae JSAE_SEED=1 JSAE_ENV_STEPS=${JSAE_ENV_STEPS:-2000000}
export JSAE_RUN=gridworld JSAE_RECOMMENDER_RUN=recommender RUST_LOG=info
# three distinct free host ports, held open together while they are chosen: one at a time, the
# kernel may hand the same port out twice (CI once gave the embedder's port to the learner too)
read -r JSAE_EMBEDDER_PORT JSAE_LEARNER_PORT JSAE_RECOMMENDER_PORT < <(python3 -c '
import socket
held = [socket.socket() for _ in range(3)]
for s in held:
    s.bind(("0.0.0.0", 0))
print(*(s.getsockname()[1] for s in held))')
export JSAE_EMBEDDER_PORT JSAE_LEARNER_PORT JSAE_RECOMMENDER_PORT
work="$(mktemp -d /tmp/jsae-compose.XXXXXX)"
chmod 755 "$work"
export JSAE_CONFIG_FILE="$work/config.toml"
cat >"$JSAE_CONFIG_FILE" <<'EOF'
actors = 2
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
chmod 644 "$JSAE_CONFIG_FILE"
compose() { docker-compose -f "$root/deploy/docker-compose.yml" --project-directory "$root/deploy" "$@"; }
teardown() {
    local rc=$?
    step "teardown (exit $rc)"
    if [[ $rc != 0 ]]; then
        compose --profile tools logs --no-color --tail 30 2>&1 | tail -120 || true
    fi
    compose --profile tools down --volumes --remove-orphans --timeout 5 >/dev/null 2>&1 || true
    local left
    left="$(docker ps -aq --filter "label=com.docker.compose.project=$COMPOSE_PROJECT_NAME")"
    left+="$(docker volume ls -q --filter "label=com.docker.compose.project=$COMPOSE_PROJECT_NAME")"
    left+="$(docker network ls -q --filter "label=com.docker.compose.project=$COMPOSE_PROJECT_NAME")"
    [[ -z "$left" ]] && echo "compose-test: torn down: no container, network or volume left" \
        || echo "compose-test: left behind: $left" >&2
    rm -rf "$work"
    exit $rc
}
trap teardown EXIT
# the shared bearer token (the compose secret jsae_auth_token): the caller's
# JSAE_HOST_TOKEN_FILE (relative to deploy/, as compose reads it), else a throw-away one in
# $work, removed with it; deploy/token is never read or written
if [[ -z "${JSAE_HOST_TOKEN_FILE:-}" ]]; then
    JSAE_HOST_TOKEN_FILE="$work/token"
    head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' >"$JSAE_HOST_TOKEN_FILE"
    # compose bind-mounts it as it is: the containers' user (uid 10001) must read it
    chmod 644 "$JSAE_HOST_TOKEN_FILE"
elif [[ "$JSAE_HOST_TOKEN_FILE" != /* ]]; then
    JSAE_HOST_TOKEN_FILE="$root/deploy/$JSAE_HOST_TOKEN_FILE"
fi
export JSAE_HOST_TOKEN_FILE
[[ -r "$JSAE_HOST_TOKEN_FILE" ]] || fail "JSAE_HOST_TOKEN_FILE=$JSAE_HOST_TOKEN_FILE cannot be read"

step "1. build the images (PROFILE=$profile)"
PROFILE="$profile" TAG="$JSAE_IMAGE" "$root/deploy/build-images.sh"
size=$(docker image inspect -f '{{.Size}}' "$JSAE_IMAGE")
echo "image $JSAE_IMAGE: $((size / 1000000)) MB"

step "2. train a small recommender run into the volume (one-off train service)"
compose run --rm train train --config /etc/jsae/config.toml --env recommender --algo ppo \
    --one-process --env-steps 4096 --eval-episodes 5 --quiet --out /runs/recommender >/dev/null
compose run --rm --entrypoint test train -f /runs/recommender/summary.json \
    || fail "the recommender run has no summary.json"

step "3. start the stack: embedder, learner, 2 actors, recommender"
up_at=$(date +%s.%N)
compose up -d --scale actor=2 embedder learner actor recommender
serving() { "$bindir/jsae" health --addr "127.0.0.1:$1" --service "$2" --timeout-ms 500 >/dev/null 2>&1; }
for svc in "embedder $JSAE_EMBEDDER_PORT jsae.v1.Embedder" "learner $JSAE_LEARNER_PORT jsae.v1.Learner" \
    "recommender $JSAE_RECOMMENDER_PORT jsae.v1.Recommender"; do
    set -- $svc
    for _ in $(seq 600); do serving "$2" "$3" && break; sleep 0.1; done
    serving "$2" "$3" || fail "$1 never answered SERVING"
    echo "$1: SERVING $(python3 -c "print(f'{$(date +%s.%N) - $up_at:.2f}')") s after up"
done
# published on loopback only (JSAE_PUBLISH_ADDR's default): not on every interface
for svc in "embedder 50051" "learner 50052" "recommender 50060"; do
    set -- $svc
    bound="$(compose port "$1" "$2")"
    [[ "$bound" == 127.0.0.1:* ]] || fail "$1 is published on $bound, not on 127.0.0.1 only"
done
echo "ports: published on 127.0.0.1 only"
for svc in embedder learner recommender; do
    for _ in $(seq 60); do
        [[ "$(docker inspect -f '{{.State.Health.Status}}' "$(compose ps -q $svc)")" == healthy ]] && break
        sleep 1
    done
    [[ "$(docker inspect -f '{{.State.Health.Status}}' "$(compose ps -q $svc)")" == healthy ]] \
        || fail "$svc's compose healthcheck is not healthy"
done
echo "compose healthchecks (jsae health): embedder, learner, recommender healthy"

metrics_rows() {
    compose exec -T learner sh -c "wc -l < /runs/$JSAE_RUN/metrics.csv" 2>/dev/null | tr -d ' \r' || echo 0
}
wait_rows() {
    for _ in $(seq 600); do
        [[ "$(metrics_rows)" -gt "$1" ]] && return 0
        sleep 0.5
    done
    fail "the learner did not pass $1 metrics rows"
}

step "4. kill one actor mid-run; --scale brings up a replacement"
wait_rows 3
read -r victim _ <<<"$(compose ps -q actor | tr '\n' ' ')"
docker kill "$victim" >/dev/null
echo "killed actor container ${victim:0:12} at metrics row $(metrics_rows)"
docker rm -f "$victim" >/dev/null
compose up -d --no-recreate --scale actor=2 actor
actors="$(compose ps -q actor)"
[[ $(wc -l <<<"$actors") == 2 ]] || fail "--scale actor=2 did not give 2 actors"
grep -q "${victim:0:12}" <<<"$actors" && fail "the killed actor is still there"
replacement="$(grep -v "${victim:0:12}" <<<"$actors" | tail -1)"
rows_at_replacement=$(metrics_rows)

step "5. restart the learner; the actors reconnect by themselves"
wait_rows $((rows_at_replacement + 2))
starts_before="$(for c in $actors; do docker inspect -f '{{.State.StartedAt}}' "$c"; done)"
compose restart -t 10 learner
rows_at_restart=$(metrics_rows)
wait_rows $((rows_at_restart + 2))
learner_log="$(compose logs --no-color learner)"
grep -q "resuming from the policy checkpoint" <<<"$learner_log" \
    || fail "the restarted learner did not resume from its checkpoint"
echo "learner resumed from its checkpoint; metrics rows $rows_at_restart -> $(metrics_rows)"

step "6. the run completes; summary.json from the volume"
learner="$(compose ps -q learner)"
for _ in $(seq 1800); do
    [[ "$(docker inspect -f '{{.State.Status}}' "$learner")" == exited ]] && break
    sleep 0.5
done
[[ "$(docker inspect -f '{{.State.Status}} {{.State.ExitCode}}' "$learner")" == "exited 0" ]] \
    || fail "the learner did not finish with exit 0"
for c in $actors; do
    for _ in $(seq 60); do
        [[ "$(docker inspect -f '{{.State.Status}}' "$c")" == exited ]] && break
        sleep 0.5
    done
    [[ "$(docker inspect -f '{{.State.ExitCode}} {{.RestartCount}}' "$c")" == "0 0" ]] \
        || fail "actor ${c:0:12} did not finish by itself with exit 0"
done
starts_after="$(for c in $actors; do docker inspect -f '{{.State.StartedAt}}' "$c"; done)"
[[ "$starts_before" == "$starts_after" ]] || fail "an actor was restarted"
replacement_log="$(docker logs "$replacement" 2>&1)"
grep -E "Finished after [1-9][0-9]* env steps" <<<"$replacement_log" \
    || fail "the replacement actor did not contribute"
summary="$(compose run --rm --entrypoint cat train "/runs/$JSAE_RUN/summary.json")"
echo "summary.json: $summary"
python3 - "$summary" "$JSAE_ENV_STEPS" <<'PY'
import json, sys
s = json.loads(sys.argv[1])
assert s["env"] == "gridworld-discrete" and s["env_steps"] >= int(sys.argv[2]), s
assert s["learner_updates"] > 0 and s["embedding_version"] >= 1, s
PY

step "7. Recommend from the host with the token; refused without it"
answer="$("$bindir/jsae" recommend --auth-token-file "$JSAE_HOST_TOKEN_FILE" \
    --addr "127.0.0.1:$JSAE_RECOMMENDER_PORT" --k 3 24852 13176)"
echo "Recommend: $answer"
python3 - "$answer" <<'PY'
import json, sys
a = json.loads(sys.argv[1])
assert len(a["items"]) == 3 and a["policy_version"] > 0, a
PY
# in the recommender's container: without the token (env -u drops the JSAE_AUTH_TOKEN_FILE
# compose sets) the call is refused; with the mounted secret it is answered
ask=(env -u JSAE_AUTH_TOKEN_FILE jsae recommend --addr 127.0.0.1:50060 --k 3)
if refused="$(compose exec -T recommender "${ask[@]}" 24852 2>&1 >/dev/null)"; then
    fail "a Recommend without the token was answered"
fi
grep -q Unauthenticated <<<"$refused" \
    || fail "a Recommend without the token failed otherwise: $refused"
echo "without the token: $refused"
answered="$(compose exec -T recommender "${ask[@]}" --auth-token-file /run/secrets/jsae_auth_token \
    24852 2>&1)" || fail "a Recommend with /run/secrets/jsae_auth_token failed: $answered"
echo "with /run/secrets/jsae_auth_token: answered"

step "8. passed; tearing down"
