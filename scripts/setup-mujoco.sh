#!/usr/bin/env bash
# Puts MuJoCo where the build expects it, from the two PyPI wheels (the only source here):
#   third_party/mujoco/libmujoco.so.3.17.0 (+ libmujoco.so)   from mujoco==3.17.0
#   third_party/mujoco/assets/{half_cheetah,ant}.xml            from gymnasium==1.4.0
# Idempotent and safe to run concurrently (flock). Cargo runs it through
# scripts/rustc-wrapper.sh before the first compilation, so `cargo build` needs nothing else.
# Neither the library nor the XMLs are committed (licences; size).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
dest="$root/third_party/mujoco"
lib="libmujoco.so.3.17.0"
if [[ -f "$dest/$lib" && -L "$dest/libmujoco.so" && -f "$dest/assets/ant.xml" && -f "$dest/assets/half_cheetah.xml" ]]; then
    exit 0
fi
mkdir -p "$root/third_party"
exec 9>"$root/third_party/.setup.lock"
flock 9
if [[ -f "$dest/$lib" && -L "$dest/libmujoco.so" && -f "$dest/assets/ant.xml" && -f "$dest/assets/half_cheetah.xml" ]]; then
    exit 0
fi
python="${PYTHON:-python3}"
wheels="$root/third_party/wheels"
mkdir -p "$wheels" "$dest/assets"
echo "setup-mujoco: downloading the mujoco==3.17.0 and gymnasium==1.4.0 wheels" >&2
"$python" -m pip download --quiet --disable-pip-version-check --no-deps --only-binary=:all: \
    --dest "$wheels" mujoco==3.17.0 gymnasium==1.4.0 >&2 \
    || { echo "setup-mujoco: pip download failed (needs python3 with pip and the package index)" >&2; exit 1; }
"$python" - "$wheels" "$dest" "$lib" <<'PY'
import glob, os, sys, zipfile
wheels, dest, lib = sys.argv[1:]
def extract(pattern, member, target):
    (wheel,) = glob.glob(os.path.join(wheels, pattern))
    with zipfile.ZipFile(wheel) as z, z.open(member) as src, open(target + ".tmp", "wb") as out:
        out.write(src.read())
    os.replace(target + ".tmp", target)
extract("mujoco-3.17.0-*.whl", "mujoco/" + lib, os.path.join(dest, lib))
for xml in ("half_cheetah.xml", "ant.xml"):
    extract("gymnasium-1.4.0-*.whl", "gymnasium/envs/mujoco/assets/" + xml,
            os.path.join(dest, "assets", xml))
PY
chmod 755 "$dest/$lib"
ln -sfn "$lib" "$dest/libmujoco.so"
echo "setup-mujoco: MuJoCo 3.17.0 in $dest" >&2
