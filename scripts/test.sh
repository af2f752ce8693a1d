#!/usr/bin/env bash
# README command (b): install vtlearn with the dev extras into .venv and run the default test suite
# (slow tests excluded; `scripts/test.sh -m slow` runs them). Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup_venv.sh dev
export WANDB_MODE=disabled
set +e
.venv/bin/python -m pytest "$@"
rc=$?
set -e
if [ "$rc" -eq 5 ]; then
    echo "error: pytest collected no tests: the test setup is broken" >&2
    exit 1
fi
exit "$rc"
