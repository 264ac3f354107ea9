#!/usr/bin/env bash
# One-step, idempotent set-up of flight_fdi on a fresh machine (make setup):
#   1. .venv with Python 3.11,
#   2. pinned dependencies (requirements.txt + constraints.txt): ROS 2 Jazzy wheels, rosbags, numpy,
#      scipy, colcon, pytest, ...,
#   3. the message package msg_defs/ (flight_fdi_msgs) and this package built with colcon into install/,
#   4. the venv wired so that .venv/bin/python imports rclpy, flight_fdi and flight_fdi_msgs and
#      .venv/bin/flight-fdi runs without sourcing anything,
#   5. the numba estimation kernels compiled into their on-disk cache.
# Each step is skipped when its inputs have not changed (a few seconds when all is up to date).
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
VENV="$ROOT/.venv"
PYTHON=${PYTHON:-python3.11}
say() { echo "[setup] $*"; }
die() { echo "[setup] error: $*" >&2; exit 1; }

hash_of() { cat "$@" 2>/dev/null | sha256sum | cut -c1-16; }

# --- 1. the virtual environment -------------------------------------------------------------
if [ ! -x "$VENV/bin/python" ]; then
    command -v "$PYTHON" >/dev/null || die "$PYTHON not found (flight_fdi needs Python 3.11, as ROS 2 Jazzy's wheels do)"
    say "creating .venv with $($PYTHON --version)"
    "$PYTHON" -m venv "$VENV"
fi
VPY="$VENV/bin/python"
"$VPY" -c 'import sys; assert sys.version_info[:2] == (3, 11)' \
    || die ".venv is not Python 3.11; remove .venv and run make setup again"
SITE=$("$VPY" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')

# --- 2. pinned dependencies -----------------------------------------------------------------
REQ_HASH=$(hash_of requirements.txt constraints.txt)
if [ "$(cat "$VENV/.flight_fdi-deps" 2>/dev/null)" != "$REQ_HASH" ]; then
    say "installing pinned dependencies (first time: about a minute)"
    "$VPY" -m pip install --quiet --disable-pip-version-check -r requirements.txt -c constraints.txt \
        2> >(grep -v "is ignored: it is neither a file nor a directory" >&2) \
        || die "pip install failed (see above)"
    # The wheels' exported CMake targets point at the wheel builder's Python and numpy include dirs;
    # point them at this venv's before building messages.
    "$VPY" - "$VENV" <<'PYEOF'
import pathlib, re, sys, sysconfig
import numpy
venv = pathlib.Path(sys.argv[1])
py_inc = sysconfig.get_paths()["include"]
np_inc = numpy.get_include()
pat_py = re.compile(r"/opt/python/cp311-cp311/include/python3\.11")
pat_np = re.compile(r"/opt/python/cp311-cp311/lib/python3\.11/site-packages/numpy/_core/include")
n = 0
for f in (venv / "share").rglob("*.cmake"):
    text = f.read_text(errors="surrogateescape")
    new = pat_py.sub(py_inc, pat_np.sub(np_inc, text))
    if new != text:
        f.write_text(new, errors="surrogateescape")
        n += 1
print(f"[setup] pointed {n} CMake files at this venv's Python/numpy include dirs")
PYEOF
    touch "$VENV/COLCON_IGNORE"
    echo "$REQ_HASH" > "$VENV/.flight_fdi-deps"
    rm -f "$VENV/.flight_fdi-build"
fi

# --- 3. colcon build of flight_fdi_msgs and flight_fdi into install/ -------------------------
BUILD_INPUTS=$(ls tools/setup.sh msg_defs/msg/*.msg msg_defs/CMakeLists.txt msg_defs/package.xml package.xml setup.py \
    setup.cfg config/*.yaml config/models/*.yaml 2>/dev/null || true)
BUILD_HASH=$( (echo "$ROOT $REQ_HASH"; ls msg_defs/msg; cat $BUILD_INPUTS) | sha256sum | cut -c1-16)
if [ "$(cat "$VENV/.flight_fdi-build" 2>/dev/null)" != "$BUILD_HASH" ] || [ ! -d install/flight_fdi_msgs ]; then
    say "building flight_fdi_msgs and flight_fdi with colcon"
    rm -rf build/flight_fdi_msgs install/flight_fdi_msgs
    mkdir -p log
    export PATH="$VENV/bin:$PATH"
    export AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV"
    if ! colcon --log-base log build --paths msg_defs . --symlink-install \
            --event-handlers console_cohesion- console_direct- summary- status- \
            --cmake-args -DPython3_EXECUTABLE="$VPY" -DBUILD_TESTING=OFF > log/colcon-build.txt 2>&1; then
        tail -n 40 log/colcon-build.txt >&2
        die "colcon build failed (full log: log/colcon-build.txt)"
    fi
    # Make the venv find what colcon installed, without sourcing install/setup.bash:
    # the interface libraries go next to the ROS wheels' libraries (.venv/lib is on the loader path
    # the wheels set up), the Python packages on sys.path through a .pth file.
    for lib in install/flight_fdi_msgs/lib/*.so; do
        ln -sf "$ROOT/$lib" "$VENV/lib/$(basename "$lib")"
    done
    MSG_SITE=$(ls -d "$ROOT"/install/flight_fdi_msgs/lib/python3*/site-packages)
    # the repo (flight_fdi itself, edited in place), the message package, and the build folder
    # holding flight_fdi's egg-info (so the installed node scripts find their entry points)
    printf '%s\n%s\n%s\n' "$ROOT" "$MSG_SITE" "$ROOT/build/flight_fdi" > "$SITE/flight_fdi_dev.pth"
    cat > "$VENV/bin/flight-fdi" <<EOF
#!$VPY
import sys
from flight_fdi.cli.main import main
if __name__ == "__main__":  # worker processes started by spawn (Dask) import this file
    sys.exit(main())
EOF
    chmod +x "$VENV/bin/flight-fdi"
    echo "$BUILD_HASH" > "$VENV/.flight_fdi-build"
    say "built: install/flight_fdi_msgs, install/flight_fdi"
fi
# --- 4. the compiled estimation kernels -------------------------------------------------------
# numba compiles each kernel on first use (about 2 minutes for all of them on a loaded 2-core machine) and keeps the machine code in
# the __pycache__ folders beside them (cache=True); compiling here means a user's first analyze
# (either model), simulate or node start only loads it. numba itself recompiles a kernel whose
# source file changed.
KERNEL_HASH=$( (echo "$REQ_HASH"; cat flight_fdi/core/*.py flight_fdi/core/ins3d/*.py \
               flight_fdi/sim/*.py flight_fdi/warmup.py) | sha256sum | cut -c1-16)
if [ "$(cat "$VENV/.flight_fdi-kernels" 2>/dev/null)" != "$KERNEL_HASH" ]; then
    say "compiling the estimation kernels (numba cache)"
    # numba keys a cached kernel on its own file only, and the kernels inline helpers of other
    # modules (discretize, ldl): a changed core recompiles everything
    rm -f flight_fdi/core/__pycache__/*.nb[ic] flight_fdi/core/ins3d/__pycache__/*.nb[ic] \
          flight_fdi/sim/__pycache__/*.nb[ic]
    "$VPY" -m flight_fdi.warmup || die "compiling the estimation kernels failed (see above)"
    echo "$KERNEL_HASH" > "$VENV/.flight_fdi-kernels"
fi
say "ready: .venv/bin/flight-fdi, .venv/bin/python (rclpy, flight_fdi, flight_fdi_msgs)"
