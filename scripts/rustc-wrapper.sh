#!/usr/bin/env bash
# Cargo's rustc wrapper (.cargo/config.toml): makes sure MuJoCo is set up before anything
# compiles (mujoco-rs's build script needs the library) and the recommender's data sets are fetched
# (the Instacart sample, its default, and MovieLens-100K), then runs the compiler unchanged.
set -e
here="$(dirname "${BASH_SOURCE[0]}")"
if [[ ! -e "$here/../third_party/mujoco/libmujoco.so" || ! -e "$here/../third_party/mujoco/assets/ant.xml" ]]; then
    "$here/setup-mujoco.sh"
fi
if [[ ! -e "$here/../third_party/instacart/df_sample.csv" ]]; then
    "$here/setup-data.sh"
elif [[ ! -e "$here/../third_party/movielens/ml-100k.inter" ]]; then
    # MovieLens is no default: without it the build goes on, and a run that asks for it
    # says to run setup-data.sh
    "$here/setup-data.sh" || echo "rustc-wrapper: MovieLens-100K not fetched; building on" >&2
fi
exec "$@"
