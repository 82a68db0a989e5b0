#!/usr/bin/env bash
# Regenerate the committed default classifier (models/classifier/) from simulated t100 traces:
# the six classes x 8 units (seeds 100-107, TRAIN_UNIT_SEEDS in core/diagnosis/evaluation.py) x the
# profiles sine:0.01, steps, multilevel, chirp (300 s each) and mission (600 s), plus the six
# classes x 8 more units (108-115, MISSION_UNIT_SEEDS) x mission (1200 s), at 10 Hz, with
# residuals of models/nominal; trained with seed 0 (20 s windows).
# Usage: scripts/make_classifier_model.sh [OUT_DIR [NOMINAL_DIR]]   (about 6-8 min on 2 cores)
# Same code, data and seed give the same weights (model_id); the card's "created" time changes.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out="${1:-$root/models/classifier}"
nominal="${2:-$root/models/nominal}"
data="$(mktemp -d)"
trap 'rm -rf "$data"' EXIT
python - "$data" <<'PY'
import sys
from pathlib import Path

from thruster_fdd_shore.core.diagnosis.evaluation import training_traces
from thruster_fdd_shore.core.traces.csv_io import write_trace_csv

for name, trace in training_traces():
    write_trace_csv(trace, Path(sys.argv[1]) / f"{name}.csv")
PY
thruster-fdd train classifier --data "$data" --nominal "$nominal" --out "$out" --seed 0
