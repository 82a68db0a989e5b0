#!/usr/bin/env bash
# Make the small MCAP recordings in bags/ that the test suite replays through the real nodes:
# one per condition (t100, mission-like command profile, 120 s at 10 Hz, an unseen unit each)
# and one with a fault starting mid-run (multilevel profile: after the onset the thruster must
# work for the fault to be observable; a fault that starts while the mission-like profile only
# station-keeps is a known blind spot, see README "Diagnosis"). Ground-truth labels travel in
# each file's metadata.
# Usage (after `. scripts/bootstrap.sh`): scripts/make_bags.sh [OUT_DIR]   (about 10 s)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out="${1:-$root/bags}"
mkdir -p "$out"
seed=901
for condition in nominal_15v nominal_13v nominal_11v8 broken_blade_1 broken_blade_2 biofouling; do
    thruster-fdd simulate --preset t100 --condition "$condition" --signal mission \
        --duration 120 --rate 10 --seed "$seed" --thruster-id t0 --out "$out/$condition.mcap"
    seed=$((seed + 1))
done
thruster-fdd simulate --preset t100 --condition nominal_15v --signal multilevel --duration 180 \
    --rate 10 --seed 950 --fault-at 90 --fault-condition broken_blade_1 --thruster-id t0 \
    --out "$out/fault_broken_blade_1_at_90s.mcap"
