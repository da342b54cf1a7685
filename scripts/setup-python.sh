#!/usr/bin/env bash
# The Python environment the tests and benchmarks use, a venv in .venv with:
#   gymnasium[mujoco]==1.4.0, mujoco==3.17.0: the MuJoCo parity test, the step-rate benchmark;
#   grpcio, grpcio-tools, grpcio-health-checking 1.76.0: the Recommender client test (another
#     language against wire/proto/);
#   kubernetes-validate==1.37.0: the offline check of deploy/k8s;
#   mcap==1.6.0, mcap-protobuf-support==0.6.0: recordings read back by a third-party reader;
#   tensorboard==2.21.0: event files read back by TensorBoard's own reader;
#   and the project's own package, python/ (jsae.envs, jsae.recommender).
# Idempotent and safe to run concurrently; prints the venv's python. Override the location
# with JSAE_VENV.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${JSAE_VENV:-$root/.venv}"
stamp="$venv/.jsae-ready-gymnasium-1.4.0-mujoco-3.17.0-grpcio-1.76.0-health-k8sv-1.37.0-mcap-1.6.0-tb-2.21.0"
if [[ ! -f "$stamp" ]]; then
    mkdir -p "$(dirname "$venv")"
    exec 9>"$venv.lock"
    flock 9
    if [[ ! -f "$stamp" ]]; then
        echo "setup-python: creating $venv (gymnasium, mujoco, grpcio, kubernetes-validate, mcap, tensorboard)" >&2
        rm -rf "$venv"
        "${PYTHON:-python3}" -m venv "$venv" >&2
        "$venv/bin/python" -m pip install --quiet --disable-pip-version-check \
            "gymnasium[mujoco]==1.4.0" "mujoco==3.17.0" \
            "grpcio==1.76.0" "grpcio-tools==1.76.0" "grpcio-health-checking==1.76.0" \
            "kubernetes-validate==1.37.0" \
            "mcap==1.6.0" "mcap-protobuf-support==0.6.0" "tensorboard==2.21.0" >&2
        touch "$stamp"
    fi
fi
# The project's own package (python/: jsae.envs, the environment worker `jsae train --env
# gym:ID` starts, and jsae.recommender), built from this checkout's proto: reinstalled when
# python/ or the proto changed.
sum="$(cd "$root" && find python/pyproject.toml python/setup.py python/jsae wire/proto/jsae.proto \
    -type f \( -name '*.py' -o -name '*.toml' -o -name '*.proto' \) -not -path '*/_proto/*' \
    -print0 | sort -z | xargs -0 sha256sum | sha256sum | cut -c1-16)"
package_stamp="$venv/.jsae-package-$sum"
if [[ ! -f "$package_stamp" ]]; then
    exec 9>"$venv.lock"
    flock 9
    if [[ ! -f "$package_stamp" ]]; then
        echo "setup-python: installing the jsae package (python/) into $venv" >&2
        "$venv/bin/python" -m pip install --quiet --disable-pip-version-check "$root/python" >&2
        rm -f "$venv"/.jsae-package-*
        touch "$package_stamp"
    fi
fi
echo "$venv/bin/python"
