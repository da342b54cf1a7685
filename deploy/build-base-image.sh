#!/usr/bin/env bash
# Builds the runtime base image locally, for machines whose Docker engine has no registry to
# pull from: debootstrap a minimal Debian bookworm (the release the binaries are built on, so
# glibc matches) into a folder and `docker import` it as jsae-base:bookworm.
# Idempotent: does nothing when the tag exists (FORCE=1 rebuilds). Needs root (or sudo),
# debootstrap (`apt-get install debootstrap`) and the Debian package mirror of
# /etc/apt/sources.list.d (override with MIRROR=...).
# Elsewhere, skip this and build deploy/Dockerfile with its default BASE (debian:bookworm-slim).
set -euo pipefail
tag="${BASE_TAG:-jsae-base:bookworm}"
if [[ -z "${FORCE:-}" ]] && docker image inspect "$tag" >/dev/null 2>&1; then
    echo "build-base-image: $tag exists" >&2
    exit 0
fi
if ! command -v debootstrap >/dev/null && [[ "$(id -u)" == 0 ]] && command -v apt-get >/dev/null; then
    echo "build-base-image: installing debootstrap" >&2
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq debootstrap >&2 \
        || { apt-get update -qq >&2 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq debootstrap >&2; }
fi
command -v debootstrap >/dev/null || {
    echo "build-base-image: debootstrap is missing (apt-get install debootstrap)" >&2
    exit 1
}
mirror="${MIRROR:-}"
if [[ -z "$mirror" ]]; then
    mirror="$(grep -hoE '^(URIs: |deb )[^ ]*debian/?( |$)' /etc/apt/sources.list.d/*.sources \
        /etc/apt/sources.list 2>/dev/null | head -1 | sed -E 's/^(URIs: |deb )//; s/ *$//' || true)"
fi
[[ -n "$mirror" ]] || {
    echo "build-base-image: no Debian mirror in /etc/apt/sources*; set MIRROR=URL" >&2
    exit 1
}
sudo=""
[[ "$(id -u)" == 0 ]] || sudo="sudo"
root="$(mktemp -d /tmp/jsae-base.XXXXXX)"
trap '$sudo rm -rf "$root"' EXIT
echo "build-base-image: debootstrap bookworm from $mirror" >&2
$sudo debootstrap --variant=minbase bookworm "$root" "$mirror" >&2
# smaller: no package lists, docs or locales in the image
$sudo rm -rf "$root"/var/lib/apt/lists/* "$root"/var/cache/apt/*.bin "$root"/usr/share/doc/* \
    "$root"/usr/share/man/* "$root"/usr/share/locale/*
$sudo tar -C "$root" -c . | docker import --change 'CMD ["/bin/bash"]' - "$tag" >/dev/null
echo "build-base-image: $tag ($(docker image inspect -f '{{.Size}}' "$tag") bytes)" >&2
