#!/bin/bash
# bench/plan_fit_last_rows.md: lane A (core 0) the paper task's plan_fit models of seeds 5-7, each
# solved for every robust profile, then crank compare; lane B (core 1) the wide lines' seed-0
# models, then both tubes over Monte-Carlo seeds on each; then, on whichever lane ends first, the
# tubes on paper-5 (usage: CLONE=... OUT=... plan_fit_last_lanes.sh A|B).
set -u
cd "$CLONE"
export OMP_NUM_THREADS=1 CRANK_ROLLOUT_THREADS=1
STOP=1940
case "$1" in A) C=0 ;; B) C=1 ;; *) echo "lane A or B" >&2; exit 2 ;; esac
mkdir -p "$OUT/cmp" "$OUT/tubes"
printf '[train]\nplan_fit = true\n' > "$OUT/plan_fit.toml"
late() {  # step: true (and says so) past the stopping time
  if [[ "$(date +%H%M)" > "$STOP" ]]; then echo "$(date +%T) $1 not started ($STOP)"; return 0; fi
  return 1
}
cli() { taskset -c "$C" "$CLONE/.venv/bin/crank" "$@"; }
model() {  # name seed variability
  late "$1" && return 1
  echo "$(date +%T) model $1"
  cli run --seed "$2" --variability "$3" --config "$OUT/plan_fit.toml" --heldout-runs 0 \
    --no-figures --logs "$OUT" --name "$1" > "$OUT/$1.log" 2>&1 || { echo "$(date +%T) $1 failed"; return 1; }
}
profiles() {  # seed: paper-S's folder for crank compare, its ocp.json every robust profile
  local run="$OUT/paper-$1" dir="$OUT/cmp/paper-$1"
  late "solve paper-$1" && return 1
  mkdir -p "$dir"
  for f in config.json report.md dataset.mcap model.pt; do ln "$run/$f" "$dir/$f"; done
  echo "$(date +%T) solve paper-$1"
  cli solve --model "$run/model.pt" --profiles robust,robust-fb,robust-pd --seed "$1" \
    --out "$dir/ocp.json" > "$dir.solve.log" 2>&1 || echo "$(date +%T) solve paper-$1 failed"
}
tubes() {  # model name
  late "tubes $1" && return 1
  mkdir -p "$OUT/tubes/$1" && cp "$OUT/$1/model.pt" "$OUT/tubes/$1/model.pt" \
    || { echo "$(date +%T) tubes $1: no model"; return 1; }
  echo "$(date +%T) tubes $1"
  taskset -c "$C" "$CLONE/.venv/bin/python" bench/bench_tasks.py --model "$OUT/tubes/$1/model.pt" \
    --profiles robust-fb,robust-pd --mc-seeds 0-4 --runs 1000 --second-stage 9000 \
    --heldout-seed 20261281 --out tasks_mc.json > "$OUT/tubes/$1.log" 2>&1 \
    || echo "$(date +%T) tubes $1 failed"
}
case "$1" in
  A) for S in 5 6 7; do model "paper-$S" "$S" paper && profiles "$S"; done
     if ! late compare; then
       echo "$(date +%T) compare"
       cli compare "$OUT"/cmp/paper-{5,6,7} --heldout-runs 1000 --heldout-seed 20261280 \
         --out "$OUT/compare" > "$OUT/compare.log" 2>&1 || echo "$(date +%T) compare failed"
     fi ;;
  B) model line-15 0 line-15; model line-30 0 line-30
     tubes line-15; tubes line-30 ;;
esac
mkdir "$OUT/tubes/paper-5.claim" 2>/dev/null && tubes paper-5
echo "$(date +%T) done"
