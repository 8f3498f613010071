#!/usr/bin/env bash
# Issue 19's training campaign: fast-PPO runs, one after another, resumable.
#
#   bash studies/learned_runs.sh [RUNS_DIR] [MINUTES] -- VARIANT:SEED[:CONFIG] ...
#   e.g. bash studies/learned_runs.sh runs/ppo_fast 12 -- Airpel-2m:0 Numatics-2m:2 \
#            Numatics-2m:0:ppo_fast-pure-numatics-2m
#
# Each run trains into RUNS_DIR/<variant>-s<seed> (or <config>-s<seed> when a config is
# named; default configs/agents/ppo_fast-<variant>.yaml) for MINUTES of wall time; a run
# with a checkpoint but no actor.npz (stopped mid-way) resumes from it, a finished one is
# skipped. Then the multi-seed table of each variant:
#   python -m pneumatic_env.agents.evaluate_seeds RUNS_DIR/<variant>-s* --actor actor_best.npz
set -euo pipefail
runs=${1:-runs/ppo_fast}
minutes=${2:-12}
shift 2 || true
[ "${1:-}" = "--" ] && shift
for item in "$@"; do
    IFS=: read -r variant seed config <<<"$item"
    lower=$(echo "$variant" | tr '[:upper:]' '[:lower:]')
    config=${config:-ppo_fast-$lower}
    if [ "$config" = "ppo_fast-$lower" ]; then out="$runs/$variant-s$seed"; else out="$runs/$config-s$seed"; fi
    if [ -f "$out/actor.npz" ]; then
        echo "done already: $out"
        continue
    fi
    resume=()
    [ -f "$out/checkpoint.pt" ] && resume=(--resume)
    echo "$(date -u +%H:%M:%S) training $out ${resume[*]}"
    pneumatic-env train --algo ppo_fast --env "pneumatic_env/ForceTrack-$variant-v0" \
        --config "configs/agents/$config.yaml" --seed "$seed" --minutes "$minutes" \
        --out "$out" "${resume[@]}"
done
