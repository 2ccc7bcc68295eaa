#!/usr/bin/env bash
# Set up and run the main job, printing a summary at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
. .venv/bin/activate
# The whole simulated stack. A finished earlier run's checkpoint would make the learner resume at its
# end, so it is kept aside (never deleted) and this run starts fresh.
if [ -d runs/stack/learner ]; then mv runs/stack/learner "runs/stack/learner-$(date +%Y%m%d-%H%M%S)"; fi
adaptiveh up configs/sim.yaml
