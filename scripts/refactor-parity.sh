#!/usr/bin/env bash
# Issue 44's check that moving code changed no result: three one-process runs (gridworld-discrete
# JSAE and HalfCheetah PPO, seed 1, default settings; recommender PPO, seed 1, whose defaults
# count the policy's prior from the logged purchases and pre-train on them, over 40,000 env
# steps) give summary.json and metrics.csv equal to
# the ones committed in results/refactor-parity/ (made at the revision before the move), in
# every field but the wall time and what follows from it or names the build
# (wall_seconds, steps_per_second, started_unix_s, git_commit, command_line).
#   cargo build --release -p jsae-cli && scripts/refactor-parity.sh          check
#   scripts/refactor-parity.sh --record                                     write the reference
set -euo pipefail
cd "$(dirname "$0")/.."
jsae="${JSAE:-target/release/jsae}"
reference=results/refactor-parity
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
runs=("gridworld-discrete jsae" "half-cheetah ppo" "recommender ppo --set env_steps=40000")
for run in "${runs[@]}"; do
    read -r env algo extra <<<"$run"
    # shellcheck disable=SC2086 # extra: more flags, split on spaces
    "$jsae" train --env "$env" --algo "$algo" --seed 1 --one-process $extra \
        --out "$work/$env-$algo" >"$work/$env-$algo.log" 2>&1 \
        || { cat "$work/$env-$algo.log"; exit 1; }
done
if [[ "${1:-}" == "--record" ]]; then
    for run in "${runs[@]}"; do
        read -r env algo _ <<<"$run"
        mkdir -p "$reference/$env-$algo"
        cp "$work/$env-$algo"/{summary.json,metrics.csv} "$reference/$env-$algo/"
    done
    echo "refactor-parity: reference written to $reference"
    exit 0
fi
python3 - "$reference" "$work" "${runs[@]}" <<'PY'
import csv, json, sys
reference, work, runs = sys.argv[1], sys.argv[2], sys.argv[3:]
wall = {"wall_seconds", "steps_per_second", "started_unix_s", "git_commit", "command_line"}
failed = False
for run in runs:
    name = "-".join(run.split()[:2])
    old = json.load(open(f"{reference}/{name}/summary.json"))
    new = json.load(open(f"{work}/{name}/summary.json"))
    for key in sorted(set(old) | set(new)):
        if key not in wall and old.get(key) != new.get(key):
            print(f"{name}: summary.json {key}: {old.get(key)!r} before, {new.get(key)!r} now")
            failed = True
    old_rows = list(csv.DictReader(open(f"{reference}/{name}/metrics.csv")))
    new_rows = list(csv.DictReader(open(f"{work}/{name}/metrics.csv")))
    if len(old_rows) != len(new_rows):
        print(f"{name}: metrics.csv has {len(new_rows)} rows, {len(old_rows)} before")
        failed = True
    for i, (o, n) in enumerate(zip(old_rows, new_rows)):
        if o.keys() != n.keys():
            print(f"{name}: metrics.csv columns differ")
            failed = True
            break
        diff = [k for k in o if k not in wall and o[k] != n[k]]
        if diff:
            print(f"{name}: metrics.csv row {i + 1} differs in {diff}")
            failed = True
            break
    print(f"{name}: {'differs' if failed else 'identical but for wall time'} "
          f"({len(new_rows)} rows, eval return {new['eval_return_mean']})")
sys.exit(1 if failed else 0)
PY
