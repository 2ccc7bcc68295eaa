#!/usr/bin/env bash
# Create .venv-franka-sim with PyPI franka-sim (the FCI emulator: communication constraints, motion limits)
# and its pins (numpy 1.26.4, mujoco 3.2). Its own virtualenv because the main .venv has numpy 2 and
# mujoco 4. Idempotent: does nothing when the pinned version is already installed.
# bench/franka_sim_stream.py starts it through tests/franka_simulators.py's FrankaSimServer.
set -euo pipefail
cd "$(dirname "$0")/.."
VERSION=${FRANKA_SIM_VERSION:-1.1.7}
VENV=.venv-franka-sim
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
if [ -x "$VENV/bin/python" ] && "$VENV/bin/python" -c "
import importlib.metadata as m, sys
sys.exit(m.version('franka-sim') != '$VERSION')" 2>/dev/null; then
  echo "$VENV: franka-sim $VERSION already installed"
  exit 0
fi
[ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q "franka-sim==$VERSION"  # pulls numpy==1.26.4, mujoco>=3.2,<3.3
"$VENV/bin/python" -c "import franka_sim, mujoco, numpy; print('$VENV: franka-sim', '$VERSION', \
'mujoco', mujoco.__version__, 'numpy', numpy.__version__)"
