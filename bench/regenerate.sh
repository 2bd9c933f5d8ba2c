#!/usr/bin/env bash
# Every published table of the project, flown again where what it shows can change: each
# table carries a behaviour stamp (atc_nf_env.experiments.behaviour: hashes of what the
# code flies on a fixed probe set, for the parts the table depends on, and of its command),
# and a table whose stamp matches today's code and whose command is unchanged is skipped.
# Tables of timings depend on "build" (the code fingerprint): any code change flies them
# again. The commands run in the order their inputs need (the MPC's reproduction first:
# the agent studies reuse it with --reuse-mpc), then the model cards, then BENCHMARKS.md.
# Before anything flies, the venv must hold every library a table to fly needs.
# Run it on an otherwise idle machine: the tables' timings are measured as they are
# written. Logs: out/regenerate/NN-name.log.
#
#   bash bench/regenerate.sh            # every stale table
#   bash bench/regenerate.sh studies    # REPRODUCTION.md, docs/figures, agents/results/, the model zoo table, cards
#   bash bench/regenerate.sh benchmarks # BENCHMARKS.md
#   FORCE=1 bash bench/regenerate.sh    # every table, fresh or not
#   FROM=2 bash bench/regenerate.sh     # from the second command on (after a failure)
#   ONLY=mpc-dense,nf-floor bash bench/regenerate.sh   # only the tables named (the names below)
#   SKIP=bench-kernel,bench-envs bash bench/regenerate.sh   # every table but those named
#   DRY=1 bash bench/regenerate.sh      # say which tables are stale, fly nothing
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-.venv/bin/python}
WHAT=${1:-all}
FROM=${FROM:-1}
FORCE=${FORCE:-0}
DRY=${DRY:-0}
ONLY=${ONLY:-}
SKIP=${SKIP:-}
LOGS=out/regenerate
mkdir -p "$LOGS"
step=0

# The libraries some table needs: the agents' studies torch and Stable-Baselines3, the
# offline study Minari. A regeneration that cannot run a row fails before it starts.
"$PYTHON" - <<'PY'
import importlib.util, sys
missing = [m for m in ("torch", "stable_baselines3", "minari") if importlib.util.find_spec(m) is None]
if missing:
    sys.exit(f"regenerate: this venv lacks {', '.join(missing)}; every table must be able to run its rows "
             "(make .venv/bin/atc-nf builds the venv that has them)")
PY

# A study refuses to resume runs flown by another build: the run folders of a study that
# flies again are set aside (out/previous/, replaced each time), not resumed.
set_aside() {
    local study
    for study in "$@"; do
        if [[ -d out/$study ]]; then
            mkdir -p out/previous
            rm -rf "out/previous/$study"
            mv "out/$study" "out/previous/$study"
        fi
    done
}

selected() {  # selected NAME: whether ONLY and SKIP (comma-separated names) let NAME fly
    [[ -z $ONLY || ,$ONLY, == *,$1,* ]] && [[ ,$SKIP, != *,$1,* ]]
}

stamped() {  # stamped NAME FILE[#SECTION] PARTS [FOLDERS-TO-SET-ASIDE] -- COMMAND...
    step=$((step + 1))
    local name=$1 table=$2 parts=$3
    shift 3
    local folders=()
    while [[ $1 != -- ]]; do folders+=("$1"); shift; done
    shift
    ((step < FROM)) && return
    selected "$name" || return 0
    local file=${table%%#*} section=()
    [[ $table == *#* ]] && section=("${table#*#}")
    local log
    log=$(printf '%s/%02d-%s.log' "$LOGS" "$step" "$name")
    if ((FORCE == 0)); then
        if "$PYTHON" -m atc_nf_env.experiments.behaviour check "$file" "${section[@]}" --parts "$parts" -- "$@" >"$log" 2>&1; then
            echo "[$(date +%H:%M:%S)] $name: $(tail -1 "$log")"
            return
        fi
        echo "[$(date +%H:%M:%S)] $name: $(tail -1 "$log")"
    fi
    ((DRY == 1)) && return
    ((${#folders[@]})) && set_aside "${folders[@]}"
    local start=$SECONDS force=()
    ((FORCE == 1)) && force=(--force)
    echo "    $*"
    "$PYTHON" -m atc_nf_env.experiments.behaviour fly "$file" "${section[@]}" --parts "$parts" "${force[@]}" -- "$@" \
        >>"$log" 2>&1 || { echo "failed: see $log"; tail -20 "$log"; exit 1; }
    echo "    done in $((SECONDS - start)) s"
}

derived() {  # derived NAME COMMAND...: a page written from other tables' files, always rewritten
    step=$((step + 1))
    local name=$1
    shift
    ((step < FROM || DRY == 1)) && return
    selected "$name" || return 0
    local log
    log=$(printf '%s/%02d-%s.log' "$LOGS" "$step" "$name")
    echo "[$(date +%H:%M:%S)] $name: $*"
    "$@" >"$log" 2>&1 || { echo "failed: see $log"; tail -20 "$log"; exit 1; }
}

AGENTS=kernel,mpc,filter,agents
benchmark() {  # benchmark NAME TABLE FOLDER ARGS...: python -m agents.benchmark ARGS --no-progress
    local name=$1 table=$2 folder=$3
    shift 3
    stamped "$name" "$table" "$AGENTS" "$folder" -- "$PYTHON" -m agents.benchmark "$@" --table "$table" --no-progress
}

if [[ $WHAT == all || $WHAT == studies ]]; then
    stamped reproduce REPRODUCTION.md kernel,mpc reproduction -- "$PYTHON" -m atc_nf_env.experiments.reproduce --runs 1000 --write
    benchmark agents-vs-mpc agents/results/table.md agents --models agents/models/imitation_bc.zip,agents/models/imitation_dagger.zip,agents/models/finetuned_ppo.zip --runs 300 --workers 2 --reuse-mpc out/reproduction --summary agents/results/summary.json
    benchmark scratch-ppo agents/results/scratch_ppo_table.md agents_scratch --models agents/models/scratch_ppo.zip --baselines '' --runs 300 --workers 2 --out out/agents_scratch --summary agents/results/scratch_ppo_summary.json
    benchmark deepsets agents/results/deepsets_table.md agents_deepsets --models agents/models/deepsets_mixed.zip --baselines '' --runs 300 --workers 2 --scenarios converging-3,converging-4,converging-5,converging-6,converging-7,converging-8,converging-12,converging-16,random-4,random-5,random-6,random-7,random-8,random-16 --out out/agents_deepsets --summary agents/results/deepsets_summary.json
    benchmark deepsets-shield agents/results/deepsets_shield_table.md deepsets_shield --shield --models agents/models/deepsets_mixed.zip --baselines '' --scenarios random-4,random-5,random-6,random-7,random-8 --runs 100 --workers 2 --out out/deepsets_shield --summary agents/results/deepsets_shield_summary.json
    benchmark deepsets-shield-300 agents/results/deepsets_shield300_table.md agents_deepsets --shield --models agents/models/deepsets_mixed.zip --baselines '' --scenarios converging-3,converging-4,converging-5,converging-6,converging-7,converging-8,random-4,random-5,random-6,random-7,random-8 --runs 300 --workers 2 --out out/agents_deepsets --summary agents/results/deepsets_shield300_summary.json
    benchmark deepsets-shield-large agents/results/deepsets_shield_large_table.md agents_deepsets --shield --models agents/models/deepsets_mixed.zip --baselines '' --scenarios converging-12,converging-16,random-16 --runs 300 --workers 2 --out out/agents_deepsets --summary agents/results/deepsets_shield_large_summary.json
    benchmark shield-1000 agents/results/shield1000_table.md shield1000 --shield --models agents/models/finetuned_ppo.zip --baselines mpc --scenarios converging-4,converging-6,random-4,random-6 --runs 1000 --workers 1 --reuse-mpc out/reproduction --out out/shield1000 --summary agents/results/shield1000_summary.json
    benchmark deepsets-shield-1000 agents/results/deepsets_shield1000_table.md deepsets_shield1000 --shield --models agents/models/deepsets_mixed.zip --baselines mpc --scenarios converging-4,converging-6,random-4,random-6 --runs 1000 --workers 2 --reuse-mpc out/reproduction --out out/deepsets_shield1000 --summary agents/results/deepsets_shield1000_summary.json
    benchmark shield-study agents/results/shield_table.md shield --shield --models agents/models/finetuned_ppo.zip,agents/models/imitation_bc.zip,agents/models/imitation_dagger.zip --scenarios converging-4,converging-6,random-4,random-6 --runs 50 --workers 2 --out out/shield --summary agents/results/shield_summary.json
    derived cards "$PYTHON" -m agents.cards --summaries agents/results/summary.json,agents/results/deepsets_summary.json,agents/results/scratch_ppo_summary.json
    derived zoo "$PYTHON" -m agents.zoo --write
fi

if [[ $WHAT == all || $WHAT == benchmarks ]]; then
    stamped bench-kernel BENCHMARKS.md#kernel build -- "$PYTHON" bench/bench_kernel.py --write
    stamped bench-kernel-scaling BENCHMARKS.md#kernel-scaling build -- "$PYTHON" bench/bench_kernel.py --scaling --write
    stamped bench-compile BENCHMARKS.md#compile build -- "$PYTHON" bench/bench_compile.py --write
    stamped bench-envs BENCHMARKS.md#envs build -- "$PYTHON" bench/bench_envs.py --write
    stamped bench-mpc BENCHMARKS.md#mpc build -- "$PYTHON" bench/bench_mpc.py --seeds 5 --repeats 2 --write
    stamped bench-shield BENCHMARKS.md#shield build -- "$PYTHON" bench/bench_shield.py --seeds 50 --scenarios converging-4,converging-6,random-4,random-6 --write
    stamped shield-stall BENCHMARKS.md#shield-stall kernel,mpc,filter,agents -- "$PYTHON" bench/shield_stall_study.py --models agents/models/deepsets_mixed.zip --scenarios random-7,random-8 --seeds 100 --write
    stamped shield-stall-mlp BENCHMARKS.md#shield-stall-mlp kernel,mpc,filter,agents -- "$PYTHON" bench/shield_stall_study.py --models agents/models/finetuned_ppo.zip,agents/models/imitation_bc.zip,agents/models/imitation_dagger.zip --scenarios random-4,random-6 --seeds 100 --section shield-stall-mlp --write
    stamped shield-adversarial BENCHMARKS.md#shield-adversarial kernel,mpc,filter -- "$PYTHON" bench/shield_adversarial_study.py --seeds 10 --write
    stamped substep-watch BENCHMARKS.md#substep-watch kernel -- "$PYTHON" bench/substep_watch_study.py --seeds 8 --write
    stamped integration-convergence BENCHMARKS.md#integration-convergence kernel -- "$PYTHON" bench/integration_convergence_study.py --seeds 200 --write
    stamped agent-forward BENCHMARKS.md#agent-forward build -- "$PYTHON" bench/bench_agent_forward.py --seeds 20 --scenarios converging-4,random-6 --write
    stamped layout-probe BENCHMARKS.md#layout-probe build -- "$PYTHON" bench/layout_probe.py --rounds 31 --write
    stamped nf-floor BENCHMARKS.md#nf-floor kernel,stream,mpc,filter -- "$PYTHON" bench/nf_floor_study.py --shield stream-30,stream-60 --write
    stamped mpc-dense BENCHMARKS.md#mpc-dense kernel,mpc -- "$PYTHON" bench/mpc_dense_study.py --runs 20 --workers 2 --write
    stamped mpc-streams BENCHMARKS.md#mpc-streams kernel,stream,mpc -- "$PYTHON" bench/mpc_dense_study.py --settings auto,joint --scenarios '' --streams stream-30,stream-60,stream-120 --stream-runs 4 --workers 2 --write
    stamped shielded-streams BENCHMARKS.md#shielded-streams kernel,stream,mpc,filter,agents -- "$PYTHON" bench/mpc_dense_study.py --settings auto --scenarios '' --streams stream-30 --stream-runs 4 --shielded agents/models/deepsets_mixed.zip,nf-leg --workers 2 --write
    stamped generalization-grid BENCHMARKS.md#generalization-grid kernel,mpc,filter,agents -- "$PYTHON" bench/generalization_grid.py --runs 20 --workers 2 --write --figure docs/figures/generalization_grid.png
    stamped offline-bc BENCHMARKS.md#offline-bc kernel,env,mpc,filter,agents -- "$PYTHON" bench/offline_bc_study.py --seeds 3 --episodes 24 --runs 50 --write
    # The longest (about 90 min on 2 cores): last.
    stamped mpc-dense-1000 BENCHMARKS.md#mpc-dense-1000 kernel,mpc -- "$PYTHON" bench/mpc_dense_study.py --settings auto --runs 1000 --workers 2 --section mpc-dense-1000 --write
fi
echo "regenerated ($WHAT) on build $("$PYTHON" -c 'from atc_nf_env import build; print(build.fingerprint())')"
