#!/usr/bin/env bash
# bench/refused_k3.md: the refused first-round torques at k 3 without the tail check, on 4000
# held-out machines of root 20261188. Usage: bench/refused_k3.sh TASKS_SWEEP_FOLDER OUT_FOLDER
set -euo pipefail
tasks=$1; out=$2; mkdir -p "$out"
crank=${CRANK:-crank}
# seed model height samples mc_seed
while read -r name model height samples mc; do
  "$crank" solve --model "$tasks/model/$model/model.pt" --out "$out/$name.ocp.json" \
    --height "$height" --samples "$samples" --k-sigma 3 --mc-samples 1000 --mc-mode mixed \
    --tightening centred --confidence 0.95 --seed "$mc" --no-tail-check
  "$crank" heldout --ocp "$out/$name.ocp.json" --model "$tasks/model/$model/model.pt" \
    --runs 4000 --seed 20261188 --out "$out/$name.heldout.json"
done <<'LIST'
h085_s0 d89a802d033a 0.085 50,100 0
h085_s2 5513ca623e44 0.085 50,100 2
edge_s2 5513ca623e44 0.075 40,120 2
edge_s4 3182c96e2e66 0.075 40,120 4
LIST
