#!/usr/bin/env bash
# Set up everything sdhn needs, idempotently: Debian build tools if missing, the Python 3.11
# virtualenv .venv from requirements.lock (exact pins), the sdhn_msgs interfaces built with plain
# cmake into the venv, and the six ament_python packages installed in editable mode.
# A second run with nothing changed returns in about a second (stamp keyed on the inputs' hashes).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
VENV="$ROOT/.venv"
STAMPS="$ROOT/.stamps"
PYTHON="${SDHN_PYTHON:-python3.11}"
say() { printf '[setup] %s\n' "$*"; }

hash_of() { cat "$@" | sha256sum | cut -c1-16; }
# What each step depends on: change one of these files and only that step runs again.
deps_key=$(hash_of requirements.lock scripts/setup.sh)
msgs_key=$(hash_of src/sdhn_msgs/CMakeLists.txt src/sdhn_msgs/package.xml src/sdhn_msgs/msg/*.msg requirements.lock)
pkgs_key=$(hash_of src/sdhn_*/setup.py src/sdhn_*/setup.cfg src/sdhn_*/package.xml requirements.lock)
stamp_ok() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ] && [ -x "$VENV/bin/python" ]; }
mkdir -p "$STAMPS"

if stamp_ok deps "$deps_key" && stamp_ok msgs "$msgs_key" && stamp_ok pkgs "$pkgs_key"; then
  say "up to date ($VENV)"
  exit 0
fi

# --- system tools: the interface build needs cmake and a C/C++ compiler --------------------
missing=()
for tool in cmake g++ make; do command -v "$tool" >/dev/null || missing+=("$tool"); done
if [ ${#missing[@]} -gt 0 ]; then
  say "installing Debian packages for: ${missing[*]}"
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq cmake g++ make >/dev/null
fi
command -v "$PYTHON" >/dev/null || { echo "setup: $PYTHON not found (Python 3.11 is required; set SDHN_PYTHON)" >&2; exit 1; }
"$PYTHON" -c 'import sys; assert sys.version_info[:2] == (3, 11)' 2>/dev/null \
  || { echo "setup: $PYTHON is not Python 3.11 (ROS 2 Jazzy wheels exist for CPython 3.11 only)" >&2; exit 1; }

# --- Python packages ----------------------------------------------------------------------
if ! stamp_ok deps "$deps_key"; then
  [ -x "$VENV/bin/python" ] || { say "creating $VENV"; "$PYTHON" -m venv "$VENV"; }
  say "installing pinned packages from requirements.lock (pip cache reused)"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check -r requirements.lock 2>&1 \
    | grep -v "is ignored: it is neither a file nor a directory" || true
  "$VENV/bin/python" -c "import rclpy, torch, mcap, rware" \
    || { echo "setup: pinned install is incomplete (see pip output above)" >&2; exit 1; }
  # The ROS wheels' cmake exports name the include directories of the machine that built them;
  # point them at this venv's Python and NumPy headers so rosidl can build our interfaces.
  py_inc=$("$VENV/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['include'])")
  np_inc=$("$VENV/bin/python" -c "import numpy; print(numpy.get_include())")
  { grep -rl "/opt/python/cp311-cp311" "$VENV/share" --include='*.cmake' 2>/dev/null || true; } \
    | while read -r f; do
    sed -i "s#/opt/python/cp311-cp311/include/python3.11#$py_inc#g;
            s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$np_inc#g" "$f"
  done
  echo "$deps_key" > "$STAMPS/deps"
fi

# --- sdhn_msgs: rosidl generation with plain cmake (no colcon wheels exist) ------------------
if ! stamp_ok msgs "$msgs_key"; then
  say "building sdhn_msgs into the venv"
  build="$ROOT/build/sdhn_msgs"
  mkdir -p "$build"
  (
    export AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV" PATH="$VENV/bin:$PATH"
    cd "$build"
    cmake "$ROOT/src/sdhn_msgs" -DCMAKE_INSTALL_PREFIX="$VENV" -DPython3_EXECUTABLE="$VENV/bin/python" \
      -DBUILD_TESTING=OFF -DCMAKE_BUILD_TYPE=Release >cmake.log 2>&1 \
      || { tail -40 cmake.log >&2; echo "setup: cmake configure of sdhn_msgs failed (log: $build/cmake.log)" >&2; exit 1; }
    make -j"$(nproc)" install >make.log 2>&1 \
      || { tail -40 make.log >&2; echo "setup: build of sdhn_msgs failed (log: $build/make.log)" >&2; exit 1; }
  )
  echo "$msgs_key" > "$STAMPS/msgs"
fi

# --- our ament_python packages, editable so the working tree is what runs -----------------
if ! stamp_ok pkgs "$pkgs_key"; then
  say "installing sdhn_base, sdhn_sim, sdhn_policy, sdhn_train, sdhn_experiments, sdhn_bringup (editable)"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation \
    -e src/sdhn_base -e src/sdhn_sim -e src/sdhn_policy -e src/sdhn_train -e src/sdhn_experiments \
    -e src/sdhn_bringup 2>&1 | grep -v "is ignored" || true
  echo "$pkgs_key" > "$STAMPS/pkgs"
fi

ROS_LOG_DIR="${ROS_LOG_DIR:-$(mktemp -d)}" "$VENV/bin/python" -c \
  "import sdhn_msgs.msg, sdhn_base, sdhn_sim, sdhn_policy, sdhn_train, sdhn_experiments, sdhn_bringup" \
  || { echo "setup: the installed packages do not import" >&2; exit 1; }
say "ready: $VENV"
