#!/usr/bin/env bash
# Regenerate a nominal model from simulated healthy t100 traces: the three nominal supply
# voltages x (multilevel + mission) signals, 200 s each at 10 Hz (12 000 samples), trained with
# seed 0 for one NARX mode (each mode has its own network, docs/nominal_model.md). The committed
# model is series-parallel: its residuals diagnose better (scripts/compare_residual_modes.py).
# Usage: scripts/make_nominal_model.sh [--mode parallel|series-parallel] [OUT_DIR]
#   (default mode series-parallel, default OUT_DIR models/nominal)
# Same code and seed give the same weights (model_id); only the card's "created" time changes.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
mode=series-parallel
if [[ "${1:-}" == "--mode" ]]; then
    mode="${2:?--mode needs parallel or series-parallel}"
    shift 2
fi
case "$mode" in
    parallel | series-parallel) ;;
    *) echo "unknown mode '$mode' (parallel or series-parallel)" >&2; exit 2 ;;
esac
out="${1:-$root/models/nominal}"
data="$(mktemp -d)"
trap 'rm -rf "$data"' EXIT
seed=1
for condition in nominal_15v nominal_13v nominal_11v8; do
    for signal in multilevel mission; do
        thruster-fdd simulate --preset t100 --condition "$condition" --signal "$signal" \
            --duration 200 --rate 10 --seed "$seed" --out "$data/${condition}_${signal}.csv"
        seed=$((seed + 1))
    done
done
thruster-fdd train nominal --data "$data" --out "$out" --seed 0 --mode "$mode"
