#!/usr/bin/env bash
# Set up and run the main job, printing a summary at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
. .venv/bin/activate
adaptiveh train --config configs/cartpole.yaml --out runs/cartpole --fresh
