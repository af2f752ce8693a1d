#!/usr/bin/env bash
# End-to-end quickstart on a fresh machine: set up .venv (idempotent), then run the whole pipeline
# (small dataset, quick ACTOR + xAVTNet, active touches on an unseen transparent object, reconstruction,
# recognition, S-TIQF pose). A rerun resumes: finished steps are skipped.
# Usage: scripts/quickstart.sh [vtlearn quickstart options, e.g. --out runs/quickstart --tiny]
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup_venv.sh
.venv/bin/vtlearn quickstart --out runs/quickstart "$@"
