#!/usr/bin/env bash
# Installs the pinned mdbook, which builds the book in docs/ (`mdbook build docs`), into
# target/tools/bin unless it is there at that version already, and prints the binary's path.
# From the package registry with cargo (`--locked`: the versions mdbook was released with);
# without the `serve` and `watch` features (a web server and a file watcher the book's build
# does not need), with `search` (the book's search box). A few minutes on 2 cores the first time.
set -euo pipefail
cd "$(dirname "$0")/.."

version=0.5.4
root="$PWD/target/tools"
bin="$root/bin/mdbook"

if [[ -x "$bin" ]] && [[ "$("$bin" --version 2>/dev/null)" == "mdbook v$version" ]]; then
    echo "$bin"
    exit 0
fi

# built outside the checkout, so that its .cargo/config.toml (the rustc wrapper that sets up
# MuJoCo) does not apply; the build folder is kept for a later reinstall
(cd "${TMPDIR:-/tmp}" && cargo install mdbook --version "=$version" --locked \
    --no-default-features --features search \
    --root "$root" --target-dir "$root/build" >&2)

if [[ "$("$bin" --version)" != "mdbook v$version" ]]; then
    echo "install-mdbook: $bin is not mdbook v$version" >&2
    exit 1
fi
echo "$bin"
