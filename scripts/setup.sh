#!/usr/bin/env bash
# Idempotent set-up of everything advsim_ros needs on a fresh Debian machine with CPython 3.11:
#   1. Debian packages the Python wheels need (libusb-1.0-0 for open3d),
#   2. .venv with the pinned requirements (real ROS 2 Jazzy from the wheels, torch CPU, ...),
#   3. the interface packages of msg_defs/ built with rosidl and installed into the venv,
#   4. advsim_ros installed editable (console scripts for every node and the `advsim` command),
#   5. sensor_msgs_py's point-cloud helpers where the venv has none (stacks import them).
# Each step is skipped when the inputs it depends on have not changed since it last ran (a hash
# stamp in .venv/.advsim-stamps), so a second run takes about a second.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
VENV="$ROOT/.venv"
STAMPS="$VENV/.advsim-stamps"
PYTHON=${PYTHON:-python3.11}
command -v "$PYTHON" >/dev/null || PYTHON=python3

log() { printf '\033[1msetup:\033[0m %s\n' "$*"; }
fail() { printf 'setup: error: %s\n' "$*" >&2; exit 1; }
hash_of() { cat "$@" | sha256sum | cut -c1-16; }
# pip's quiet mode still warns about index locations this machine's pip configuration names but lacks.
pip_install() { "$VENV/bin/python" -m pip install -q --disable-pip-version-check "$@" 2> >(grep -v "^WARNING: Location '" >&2); }
stamp_ok() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
stamp_set() { mkdir -p "$STAMPS" && echo "$2" > "$STAMPS/$1"; }

# One set-up at a time (two shells, or a test and a developer, may both run make).
mkdir -p "$ROOT/build"
exec 9>"$ROOT/build/.setup.lock"
flock 9

"$PYTHON" -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)' \
  || fail "the ROS 2 Jazzy wheels need CPython 3.11; $PYTHON is $("$PYTHON" --version 2>&1)"

# 1. Debian packages (open3d's import needs libusb-1.0).
if ! ldconfig -p | grep -q 'libusb-1.0.so.0'; then
  log "installing Debian package libusb-1.0-0 (needed by open3d)"
  [ "$(id -u)" = 0 ] || fail "libusb-1.0-0 is missing and installing it needs root: apt-get install -y libusb-1.0-0"
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
fi
# Debian's chromium and its driver: the test that opens report.html in a real headless browser
# (tests/viz/test_report_browser.py). Optional: without root, say so and go on (that test then skips).
if ! command -v chromium >/dev/null || ! command -v chromedriver >/dev/null; then
  if [ "$(id -u)" = 0 ]; then
    log "installing Debian packages chromium and chromium-driver (the report's browser test)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null
  else
    log "chromium is missing and installing it needs root (apt-get install -y chromium chromium-driver); its test will skip"
  fi
fi

# 2. Virtual environment with the pinned requirements.
req_hash=$(hash_of requirements/base.txt requirements/dev.txt)
if [ ! -x "$VENV/bin/python" ]; then
  log "first set-up: about 3 minutes on a 2-core machine (2.7 GB of packages into .venv; longer if pip downloads them)"
  log "creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
if ! stamp_ok requirements "$req_hash"; then
  log "installing pinned requirements into .venv (first time: several minutes)"
  pip_install --upgrade pip==26.3 setuptools==84.2.1 wheel==0.48.0
  # torch first and alone, so that nothing can pull a CUDA build in its place.
  pip_install "$(grep '^torch==' requirements/base.txt)"
  # open3d-cpu installs the same files as open3d (the CUDA build an earlier set-up installed): that one goes first.
  if "$VENV/bin/python" -m pip show -q open3d >/dev/null 2>&1; then
    "$VENV/bin/python" -m pip uninstall -y -q open3d
  fi
  pip_install -r requirements/base.txt -r requirements/dev.txt
  rm -f "$STAMPS"/msgs-* "$STAMPS/package"
  stamp_set requirements "$req_hash"
fi

# 3. Interface packages built with rosidl from the wheels into the venv prefix: advsim_msgs, and
#    tf2_msgs (/tf's TFMessage), which the wheels lack, and the Autoware messages the Autoware stack
#    adapters speak (autoware_planning_msgs: Trajectory; autoware_perception_msgs: detected, tracked
#    and predicted objects), for machines without Autoware.
build_interfaces() {
  local pkg=$1 pkg_hash
  pkg_hash=$(hash_of msg_defs/"$pkg"/CMakeLists.txt msg_defs/"$pkg"/package.xml msg_defs/"$pkg"/msg/*.msg scripts/setup.sh)
  stamp_ok "msgs-$pkg" "$pkg_hash" && return 0
  log "building $pkg (rosidl) into .venv"
  # The message wheels' exported CMake targets name the include folders of the machine that built them;
  # point them at this interpreter's and this venv's numpy.
  local py_include np_include
  py_include=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
  np_include=$("$VENV/bin/python" -c 'import numpy; print(numpy.get_include())')
  { grep -rlE '/opt/python/cp311-cp311' "$VENV/share" --include='*.cmake' || true; } | while read -r f; do
    sed -i -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$np_include#g" \
           -e "s#/opt/python/cp311-cp311/include/python3.11#$py_include#g" "$f"
  done
  rm -rf "$ROOT/build/$pkg" && mkdir -p "$ROOT/build"
  local log_file="$ROOT/build/$pkg.log"
  cmake -S msg_defs/"$pkg" -B build/"$pkg" -G "Unix Makefiles" \
    -DCMAKE_INSTALL_PREFIX="$VENV" -DCMAKE_PREFIX_PATH="$VENV" \
    -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF -DCMAKE_BUILD_TYPE=Release \
    > "$log_file" 2>&1 || { tail -40 "$log_file" >&2; fail "cmake configure of $pkg failed (log: $log_file)"; }
  cmake --build build/"$pkg" -j2 >> "$log_file" 2>&1 \
    || { tail -40 "$log_file" >&2; fail "build of $pkg failed (log: $log_file)"; }
  cmake --install build/"$pkg" >> "$log_file" 2>&1 \
    || { tail -40 "$log_file" >&2; fail "install of $pkg failed (log: $log_file)"; }
  "$VENV/bin/python" -c "import $pkg.msg" || fail "$pkg was built but does not import from the venv"
  stamp_set "msgs-$pkg" "$pkg_hash"
}
build_interfaces advsim_msgs
build_interfaces tf2_msgs
build_interfaces autoware_planning_msgs
build_interfaces autoware_perception_msgs

# 4. advsim_ros, editable: code changes need no reinstall; entry points change with setup.py.
pkg_hash=$(hash_of src/advsim_ros/setup.py src/advsim_ros/setup.cfg src/advsim_ros/package.xml)
if ! stamp_ok package "$pkg_hash"; then
  log "installing advsim_ros (editable) into .venv"
  pip_install --no-deps --no-build-isolation -e src/advsim_ros
  stamp_set package "$pkg_hash"
fi
# 5. sensor_msgs_py (point-cloud helpers that stacks import; the ROS 2 wheels lack it): advsim's own
#    (src/sensor_msgs_py_compat), only where none imports, so a full ROS install keeps its own.
#    Installed again when it changed, if it is ours that is there (the stamp says so).
compat_hash=$(hash_of src/sensor_msgs_py_compat/pyproject.toml src/sensor_msgs_py_compat/sensor_msgs_py/*.py)
if ! stamp_ok sensor_msgs_py "$compat_hash" \
   && { [ -f "$STAMPS/sensor_msgs_py" ] || ! "$VENV/bin/python" -c 'import sensor_msgs_py' 2>/dev/null; }; then
  log "installing sensor_msgs_py (point_cloud2 helpers, advsim's own) into .venv"
  pip_install --no-deps --no-build-isolation src/sensor_msgs_py_compat
  stamp_set sensor_msgs_py "$compat_hash"
fi
log "ready: . .venv/bin/activate  (advsim --help)"
