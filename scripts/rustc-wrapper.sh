#!/usr/bin/env bash
# Cargo's rustc wrapper (.cargo/config.toml): makes sure MuJoCo is set up before anything
# compiles (mujoco-rs's build script needs the library) and the Instacart sample is fetched (the
# recommender's default data), then runs the compiler unchanged.
set -e
here="$(dirname "${BASH_SOURCE[0]}")"
if [[ ! -e "$here/../third_party/mujoco/libmujoco.so" || ! -e "$here/../third_party/mujoco/assets/ant.xml" ]]; then
    "$here/setup-mujoco.sh"
fi
if [[ ! -e "$here/../third_party/instacart/df_sample.csv" ]]; then
    "$here/setup-data.sh"
fi
exec "$@"
