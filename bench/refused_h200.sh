#!/usr/bin/env bash
# bench/refused_h200.md: the two horizon-200 models that `mean_wrap` + the plan round refused after
# the round (session 40), their torques at k 3 and at the last k the tail check tried, without the
# check, on 4000 held-out machines of root 20261190.
# Usage: bench/refused_h200.sh SWEEP_FOLDER OUT_FOLDER (SWEEP_FOLDER: bench/mean_wrap_round.md's)
set -euo pipefail
sweep=$1; out=$2; mkdir -p "$out"
crank=${CRANK:-crank}
# name second-round-solve k mc_seed
while read -r name solve k mc; do
  "$crank" solve --model "$sweep/solve/$solve.failed/model.pt" --out "$out/$name.ocp.json" \
    --horizon 200 --samples 70,130 --k-sigma "$k" --mc-samples 1000 --mc-mode mixed \
    --tightening centred --confidence 0.95 --seed "$mc" --no-tail-check
  "$crank" heldout --ocp "$out/$name.ocp.json" --model "$sweep/solve/$solve.failed/model.pt" \
    --runs 4000 --seed 20261190 --out "$out/$name.heldout.json"
done <<'LIST'
s1_k3 93328068646b 3 1
s1_k366 93328068646b 3.66 1
s3_k3 5e8a0ec04224 3 3
s3_k39 5e8a0ec04224 3.9 3
LIST
