#!/usr/bin/env bash
# Builds the jsae image from this checkout: the binaries on the host (cargo; the image has no
# toolchain), staged with libmujoco, the MuJoCo XMLs, the Instacart sample and MovieLens-100K into
# deploy/.stage, then `docker build -f deploy/Dockerfile`.
#   PROFILE=release (default) or dev: the binaries exactly as `cargo test --workspace` builds
#                   them (the same features, so after the tests nothing compiles again: CI)
#   BASE=image      the base image; default: jsae-base:bookworm, built here by
#                   deploy/build-base-image.sh when it is missing (no registry needed)
#   TAG=jsae:latest the image's tag
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
profile="${PROFILE:-release}"
tag="${TAG:-jsae:latest}"
base="${BASE:-jsae-base:bookworm}"
if [[ "$base" == jsae-base:* ]]; then
    BASE_TAG="$base" deploy/build-base-image.sh
fi
# dev: with the test targets, so that the dependencies' features are unified as for the
# tests (a dev-dependency such as proptest turns on features of shared crates) and cargo
# reuses what `cargo test` built instead of compiling the workspace a second time
flag=(--workspace --tests)
dir=debug
if [[ "$profile" == release ]]; then
    flag=(--release)
    dir=release
fi
echo "build-images: cargo build ${flag[*]} --bins" >&2
cargo build "${flag[@]}" --bins >&2
stage="deploy/.stage"
rm -rf "$stage"
mkdir -p "$stage/bin" "$stage/lib" "$stage/share/mujoco" "$stage/share/instacart" "$stage/share/movielens"
for b in jsae jsae-actor jsae-embedder jsae-learner; do
    cp "${CARGO_TARGET_DIR:-target}/$dir/$b" "$stage/bin/"
done
strip "$stage"/bin/* 2>/dev/null || true
cp third_party/mujoco/libmujoco.so.3.17.0 "$stage/lib/"
cp third_party/mujoco/assets/*.xml "$stage/share/mujoco/"
cp third_party/instacart/df_sample.csv "$stage/share/instacart/"
cp third_party/movielens/ml-100k.inter "$stage/share/movielens/"
echo "build-images: docker build $tag (BASE=$base)" >&2
docker build --quiet --build-arg "BASE=$base" -f deploy/Dockerfile -t "$tag" . >&2
echo "build-images: $tag, $(docker image inspect -f '{{.Size}}' "$tag") bytes" >&2
