#!/usr/bin/env bash
# Set up and run the default test suite (under 15 minutes on 2 cores).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# Debian packages the tests load: Chromium (the monitor's browser test drives it with Playwright, no
# browser download) and libusb-1.0-0 (pyrealsense2's library needs it to import).
need=()
[ -x /usr/bin/chromium ] || need+=(chromium)
dpkg -s libusb-1.0-0 >/dev/null 2>&1 || need+=(libusb-1.0-0)
if [ ${#need[@]} -gt 0 ] && command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
fi
. .venv/bin/activate
ruff check .
# A random test order each run (pytest-randomly); the seed is printed so that a failure can be rerun in
# the same order: RANDOMLY_SEED=N bash scripts/test.sh.
seed=${RANDOMLY_SEED:-$((RANDOM * 32768 + RANDOM))}
echo "test order: pytest-randomly seed $seed (RANDOMLY_SEED=$seed bash scripts/test.sh repeats it)"
python -m pytest -q -p no:cacheprovider -p randomly --randomly-seed="$seed" "$@"
