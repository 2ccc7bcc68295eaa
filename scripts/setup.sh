#!/usr/bin/env bash
# Create .venv (Python 3.11) and install the project with its extras. Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
. .venv/bin/activate
python -m pip install -q --upgrade pip
# CPU torch first (a local wheel here; a range would pull a multi-GB CUDA build).
python -m pip install -q "torch==2.13.0"
# franky-sim: the Franka path is tested against franky-sim. realsense: the RealSense backend is tested
# on the SDK's software_device (pyrealsense2 loads Debian's libusb-1.0-0: scripts/test.sh installs it);
# PyPI has pyrealsense2 wheels for x86_64 only, elsewhere that test is skipped.
# ray: the bench's Ray executor is tested on a local 2-CPU instance (about 240 MB, 15 s to install).
# lerobot: adaptiveh export lerobot is tested by writing and loading a LeRobotDataset.
extras="dev,baselines,franky-sim,ray,lerobot"
if [ "$(uname -m)" = x86_64 ]; then
  extras="$extras,realsense"
fi
python -m pip install -q -e ".[$extras]"
# LeRobot's dataset writer and reader, without its pins (pyproject.toml's lerobot extra says why).
python -m pip install -q --no-deps "lerobot==0.4.4" "torchvision==0.28.0"
# The sim camera renders with MuJoCo through EGL on Mesa's software rasteriser (llvmpipe): Debian's
# libegl1, libegl-mesa0 and libgl1-mesa-dri. Without them it falls back to PyBullet's TinyRenderer,
# with a warning, at a fraction of the rate.
need=()
for pkg in libegl1 libegl-mesa0 libgl1-mesa-dri; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
done
if [ ${#need[@]} -gt 0 ] && command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
fi
