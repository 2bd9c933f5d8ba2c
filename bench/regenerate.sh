#!/usr/bin/env bash
# Every stamped table of the project, flown again on the build in the working tree: the
# command printed above each table, in the order their inputs need (the MPC's reproduction
# runs first: the agent studies reuse them with --reuse-mpc), then the model cards, then
# BENCHMARKS.md. Run it after a change to any source the build fingerprint hashes
# (atc_nf_env.build.PACKAGE_SOURCES and baselines/), on an otherwise idle machine: the
# tables' timings are measured as they are written. Logs: out/regenerate/NN-name.log.
#
#   bash bench/regenerate.sh            # everything (about 105 min on 2 cores)
#   bash bench/regenerate.sh studies    # REPRODUCTION.md, docs/figures, agents/results/, the model zoo table, cards
#   bash bench/regenerate.sh benchmarks # BENCHMARKS.md
#   FROM=2 bash bench/regenerate.sh     # from the second command on (after a failure)
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-.venv/bin/python}
ATC_NF=${ATC_NF:-.venv/bin/atc-nf}
WHAT=${1:-all}
FROM=${FROM:-1}
LOGS=out/regenerate
mkdir -p "$LOGS"
step=0
if ((FROM == 1)); then
    # A study refuses to resume runs flown by another build: the last regeneration's run
    # folders are set aside (out/previous/, replaced each time), not resumed.
    if [[ $WHAT == all || $WHAT == studies ]]; then
        mkdir -p out/previous
        for study in reproduction agents agents_scratch agents_deepsets deepsets_shield deepsets_shield1000 shield shield1000; do
            if [[ -d out/$study ]]; then
                rm -rf "out/previous/$study"
                mv "out/$study" "out/previous/$study"
            fi
        done
    fi
fi

run() {  # run NAME COMMAND...: the command, its output in $LOGS, its time on the terminal
    step=$((step + 1))
    local log
    log=$(printf '%s/%02d-%s.log' "$LOGS" "$step" "$1")
    shift
    if ((step < FROM)); then
        return
    fi
    local start=$SECONDS
    echo "[$(date +%H:%M:%S)] $*"
    "$@" >"$log" 2>&1 || { echo "failed: see $log"; tail -20 "$log"; exit 1; }
    echo "    done in $((SECONDS - start)) s"
}

benchmark() {  # benchmark NAME ARGS...: python -m agents.benchmark ARGS --no-progress
    local name=$1
    shift
    run "$name" "$PYTHON" -m agents.benchmark "$@" --no-progress
}

if [[ $WHAT == all || $WHAT == studies ]]; then
    run reproduce "$ATC_NF" reproduce --runs 1000 --write
    benchmark agents-vs-mpc --models agents/models/imitation_bc.zip,agents/models/imitation_dagger.zip,agents/models/finetuned_ppo.zip --runs 300 --workers 2 --reuse-mpc out/reproduction --summary agents/results/summary.json --table agents/results/table.md
    benchmark scratch-ppo --models agents/models/scratch_ppo.zip --baselines '' --runs 300 --workers 2 --out out/agents_scratch --summary agents/results/scratch_ppo_summary.json --table agents/results/scratch_ppo_table.md
    benchmark deepsets --models agents/models/deepsets_mixed.zip --baselines '' --runs 300 --workers 2 --scenarios converging-3,converging-4,converging-5,converging-6,converging-7,converging-8,converging-12,converging-16,random-4,random-5,random-6,random-7,random-8,random-16 --out out/agents_deepsets --summary agents/results/deepsets_summary.json --table agents/results/deepsets_table.md
    benchmark deepsets-shield --shield --models agents/models/deepsets_mixed.zip --baselines '' --scenarios random-4,random-5,random-6,random-7,random-8 --runs 100 --workers 2 --out out/deepsets_shield --summary agents/results/deepsets_shield_summary.json --table agents/results/deepsets_shield_table.md
    benchmark deepsets-shield-300 --shield --models agents/models/deepsets_mixed.zip --baselines '' --scenarios converging-3,converging-4,converging-5,converging-6,converging-7,converging-8,random-4,random-5,random-6,random-7,random-8 --runs 300 --workers 2 --out out/agents_deepsets --summary agents/results/deepsets_shield300_summary.json --table agents/results/deepsets_shield300_table.md
    benchmark deepsets-shield-large --shield --models agents/models/deepsets_mixed.zip --baselines '' --scenarios converging-12,converging-16,random-16 --runs 300 --workers 2 --out out/agents_deepsets --summary agents/results/deepsets_shield_large_summary.json --table agents/results/deepsets_shield_large_table.md
    benchmark shield-1000 --shield --models agents/models/finetuned_ppo.zip --baselines mpc --scenarios converging-4,converging-6,random-4,random-6 --runs 1000 --workers 1 --reuse-mpc out/reproduction --out out/shield1000 --summary agents/results/shield1000_summary.json --table agents/results/shield1000_table.md
    benchmark deepsets-shield-1000 --shield --models agents/models/deepsets_mixed.zip --baselines mpc --scenarios converging-4,converging-6,random-4,random-6 --runs 1000 --workers 2 --reuse-mpc out/reproduction --out out/deepsets_shield1000 --summary agents/results/deepsets_shield1000_summary.json --table agents/results/deepsets_shield1000_table.md
    benchmark shield-study --shield --models agents/models/finetuned_ppo.zip,agents/models/imitation_bc.zip,agents/models/imitation_dagger.zip --scenarios converging-4,converging-6,random-4,random-6 --runs 50 --workers 2 --out out/shield --summary agents/results/shield_summary.json --table agents/results/shield_table.md
    run cards "$PYTHON" -m agents.cards --summaries agents/results/summary.json,agents/results/deepsets_summary.json,agents/results/scratch_ppo_summary.json
    run zoo "$PYTHON" -m agents.zoo --write
fi

if [[ $WHAT == all || $WHAT == benchmarks ]]; then
    run bench-kernel "$PYTHON" bench/bench_kernel.py --write
    run bench-kernel-scaling "$PYTHON" bench/bench_kernel.py --scaling --write
    run bench-compile "$PYTHON" bench/bench_compile.py --write
    run bench-envs "$PYTHON" bench/bench_envs.py --write
    run bench-mpc "$PYTHON" bench/bench_mpc.py --seeds 5 --repeats 2 --write
    run bench-shield "$PYTHON" bench/bench_shield.py --seeds 50 --scenarios converging-4,converging-6,random-4,random-6 --write
    run shield-stall "$PYTHON" bench/shield_stall_study.py --models agents/models/deepsets_mixed.zip --scenarios random-7,random-8 --seeds 100 --write
    run shield-stall-mlp "$PYTHON" bench/shield_stall_study.py --models agents/models/finetuned_ppo.zip,agents/models/imitation_bc.zip,agents/models/imitation_dagger.zip --scenarios random-4,random-6 --seeds 100 --section shield-stall-mlp --write
    run shield-adversarial "$PYTHON" bench/shield_adversarial_study.py --seeds 10 --write
    run substep-watch "$PYTHON" bench/substep_watch_study.py --seeds 8 --write
    run integration-convergence "$PYTHON" bench/integration_convergence_study.py --seeds 200 --write
    run agent-forward "$PYTHON" bench/bench_agent_forward.py --seeds 20 --scenarios converging-4,random-6 --write
    run layout-probe "$PYTHON" bench/layout_probe.py --rounds 31 --write
    run nf-floor "$PYTHON" bench/nf_floor_study.py --shield stream-30,stream-60 --write
    run mpc-dense "$PYTHON" bench/mpc_dense_study.py --runs 20 --workers 2 --write
    run mpc-streams "$PYTHON" bench/mpc_dense_study.py --scenarios '' --streams stream-30,stream-60,stream-120 --stream-runs 4 --workers 2 --write
    run shielded-streams "$PYTHON" bench/mpc_dense_study.py --settings per-cluster --scenarios '' --streams stream-30 --stream-runs 4 --shielded agents/models/deepsets_mixed.zip,nf-leg --workers 2 --write
    run generalization-grid "$PYTHON" bench/generalization_grid.py --runs 20 --workers 2 --write --figure docs/figures/generalization_grid.png
    run offline-bc "$PYTHON" bench/offline_bc_study.py --seeds 3 --episodes 24 --runs 50 --write
fi
echo "regenerated ($WHAT) on build $("$PYTHON" -c 'from atc_nf_env import build; print(build.fingerprint())')"
