#!/usr/bin/env bash
# Each test file run on its own, in its own pytest process (issue #35: a test passes alone, not only
# after its neighbours). Default-run tests only (pyproject.toml's addopts deselect the marked ones).
# Usage: bash scripts/test_each_file.sh [extra pytest args]; exits 1 naming the files that failed.
set -uo pipefail
cd "$(dirname "$0")/.."
. .venv/bin/activate
failed=()
log=$(mktemp)
trap 'rm -f "$log"' EXIT
files=$(find tests -name 'test_*.py' | sort)
n=$(echo "$files" | wc -l)
i=0
for f in $files; do
  i=$((i + 1))
  echo "[$i/$n] $f"
  python -m pytest -q -p no:cacheprovider "$f" "$@" >"$log" 2>&1
  rc=$?
  # 5: no tests collected (a file whose tests are all marked slow): nothing ran, nothing failed.
  if [ $rc -ne 0 ] && [ $rc -ne 5 ]; then
    failed+=("$f")
    tail -20 "$log"
  fi
done
if [ ${#failed[@]} -gt 0 ]; then
  echo "failed alone: ${failed[*]}"
  exit 1
fi
echo "all $n files pass alone"
