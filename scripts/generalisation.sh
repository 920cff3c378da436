#!/usr/bin/env bash
# Generalisation to maps a policy never saw: DQN and ADFQ-TS learn on the paper's fixed obstacles4 map
# (experiment=paper_obstacles1), on random maps (experiment=random_obstacles: a new obstacle layout per world and
# episode) and on random maps with the local map image in the observation (env.features.local_map=occupancy, a
# conv torso); then every learned policy plays EPISODES episodes on random maps drawn from a seed no training
# used, and on obstacles4, beside ARVI on both. The tables ($OUT/tables/<map>.md) are aia-log stats of the
# evaluations grouped by where each policy learned (trained_env.*) and by method, against ARVI.
#
#   scripts/generalisation.sh                              # 5 seeds per method and training setting
#   SEEDS=0,1 FRAMES=600 EPISODES=4 ARVI_SEEDS=0,1 ARVI_NODES=300 scripts/generalisation.sh   # a smoke run
#
# Environment variables (defaults in brackets):
#   SEEDS        learner seeds [0-4] (ranges as in scripts/reproduce.sh);  METHODS  learners [dqn,adfq_ts]
#   TRAINED_ON   training settings [paper_obstacles1 random_obstacles random_obstacles_local_map]
#   FRAMES       override of each experiment's training length [the experiment's: 200 training episodes]
#   TRAIN_OVERRIDES  more aia-train overrides, space-separated []; "resume=auto" continues the learners of a
#                stopped call from their checkpoints (a learner run folder is never trained over: without it, a
#                call over runs already there is refused for those runs) and evaluates again the ARVI seeds it had
#                not finished (no eval.json), keeping the others
#   EPISODES     evaluation episodes per policy and map [100];  EVAL_SEED  their seed [1000]
#   ARVI_SEEDS   ARVI seeds per map [0-4];  ARVI_EPISODES  episodes per ARVI seed [20]
#   ARVI_NODES   ARVI's node budget per world and plan [25000];  ARVI_MIN_RANGE  planner.min_range [2]
#   JOBS         processes in parallel [2];  OUT  output folder [outputs/generalisation]
#   PHASES       which phases run [learners,evals,arvi,tables]
# Set but empty, FRAMES and TRAIN_OVERRIDES mean what unset does; any other variable set but empty (SEEDS=, say)
# is refused in one line naming it and what it takes, as a bad value is (exit 2), before anything runs.
#
# Stopping: as scripts/reproduce.sh's (its header): SIGINT, SIGTERM or SIGUSR1 to this script reach the running
# sweep or evaluations, the script waits for them to end and exits with 128 + signal and one line saying how to
# continue (TRAIN_OVERRIDES="resume=auto", the other variables as they were).
#
# Runs go to $OUT/learners/<trained on>/<method=...,seed=...>, their evaluations to
# $OUT/evals/<map>/<trained on>/<method=...,seed=...> (an evaluation already written is kept: a stopped call
# goes on where it stopped), ARVI to $OUT/arvi/<map>/seed=<seed>.
set -euo pipefail
# given, given_some, train_extras, seed_list, parse_phases, unfinished, resuming, machine_speed, phase, run, job, throttle, drain; the stop signals' trap
# shellcheck source-path=SCRIPTDIR source=lib/protocol.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib/protocol.sh"

# Everything is checked before anything runs: a bad or empty value ends the script in one line (exit 2).
given SEEDS 0-4 "seeds, e.g. 0,1,2 or 0-19 or 0-4,10"
given METHODS dqn,adfq_ts "some of conf/method/, comma-separated"
given_some TRAINED_ON "paper_obstacles1 random_obstacles random_obstacles_local_map" "training setting"
given EPISODES 100 "a number of episodes"
given EVAL_SEED 1000 "a seed"
given ARVI_SEEDS 0-4 "seeds, e.g. 0,1,2 or 0-19 or 0-4,10 (PHASES without arvi for no ARVI)"
given ARVI_EPISODES 20 "a number of episodes"
given ARVI_NODES 25000 "a number of nodes"
given ARVI_MIN_RANGE 2 "a range in metres"
given JOBS 2 "a number of processes"
given OUT outputs/generalisation "a folder"
given PHASES learners,evals,arvi,tables "some of learners,evals,arvi,tables"
whole_number JOBS
MAPS="random_obstacles obstacles4"

# shellcheck disable=SC2153  # given sets SEEDS
SEED_LIST=$(seed_list SEEDS "$SEEDS")
ARVI_SEED_LIST=$(seed_list ARVI_SEEDS "$ARVI_SEEDS")
parse_phases "$PHASES" learners evals arvi tables
# what each training setting adds to aia-train
declare -A TRAINING=(
  [paper_obstacles1]="experiment=paper_obstacles1"
  [random_obstacles]="experiment=random_obstacles"
  [random_obstacles_local_map]="experiment=random_obstacles env.features.local_map=occupancy"
)
train_extras

mkdir -p "$OUT/tables"
OUT_ABS=$(cd "$OUT" && pwd)
machine_speed start
start=$(date +%s)

# One sweep per training setting: each method's seeds are one population, $JOBS populations at a time.
for trained in ${RUN_PHASE[learners]:+$TRAINED_ON}; do
  phase "learners on $trained: $METHODS x seeds $SEEDS, as populations"
  read -r -a setting <<< "${TRAINING[$trained]}"
  run aia-train -m hydra/launcher=population "hydra.launcher.n_jobs=$JOBS" "${setting[@]}" "method=$METHODS" \
    "seed=$SEED_LIST" threads=1 "${FRAMES_OVERRIDE[@]}" "${TRAIN_EXTRA[@]}" \
    "hydra.sweep.dir=$OUT/sweeps/learners_$trained" \
    "hydra.sweep.subdir=$OUT_ABS/learners/$trained/\${hydra.job.override_dirname}" \
    'hydra.job.config.override_dirname.exclude_keys=[experiment,env.features.local_map,threads,frames,device,resume,compile.update,compile.env,compile.policy]'
done

# evaluate CHECKPOINT MAP DIR: the policy's EPISODES episodes on MAP (env.map of its own setting), logged in DIR
evaluate() {
  # quoted: the run's folder names hold '=' and ',' (method=adfq_ts,seed=0), which Hydra's grammar reserves
  aia-eval "checkpoint='$1'" "env.map=$2" "episodes=$EPISODES" "seed=$EVAL_SEED" threads=1 "hydra.run.dir='$3'" \
    > "$3.log" 2>&1 || { cat "$3.log"; return 1; }
}
if [[ -n "${RUN_PHASE[evals]:-}" ]]; then
  phase "evaluations: every learned policy on $MAPS, $EPISODES episodes each (seed $EVAL_SEED), $JOBS at a time"
  for trained in $TRAINED_ON; do
    for checkpoint in "$OUT/learners/$trained"/*/checkpoints/last.pt; do
      [[ -f "$checkpoint" ]] || continue
      run=$(basename "$(dirname "$(dirname "$checkpoint")")")
      for map in $MAPS; do
        dir="$OUT/evals/$map/$trained/$run"
        [[ -f "$dir/eval.json" ]] && continue  # written by an earlier call
        mkdir -p "$(dirname "$dir")"
        rm -rf "$dir"  # a stopped evaluation's partial log: run logs are never overwritten
        job evaluate "$checkpoint" "$map" "$dir"
        throttle
      done
    done
  done
  drain
  if (( failed )); then echo "an evaluation failed (its output above)" >&2; exit 1; fi
fi

for map in ${RUN_PHASE[arvi]:+$MAPS}; do
  phase "ARVI (min range $ARVI_MIN_RANGE m) on $map: seeds $ARVI_SEEDS, $ARVI_EPISODES episodes each"
  env=$map
  if [[ "$map" == obstacles4 ]]; then env=obstacles1; fi  # the paper's setting 2 is obstacles4
  pending_seeds=$ARVI_SEED_LIST
  if resuming; then pending_seeds=$(unfinished "$OUT/arvi/$map" "$ARVI_SEED_LIST"); fi
  if [[ -z "$pending_seeds" ]]; then echo "-- every run is there already"; continue; fi
  run aia-eval -m hydra/launcher=population hydra.launcher.split_to_fill=true "hydra.launcher.n_jobs=$JOBS" \
    policy=arvi "env=$env" "seed=$pending_seeds" "episodes=$ARVI_EPISODES" threads=1 \
    "planner.min_range=$ARVI_MIN_RANGE" planner.time_budget=null "planner.max_nodes=$ARVI_NODES" \
    "hydra.sweep.dir=$OUT/sweeps/arvi_$map" "hydra.sweep.subdir=$OUT_ABS/arvi/$map/\${hydra.job.override_dirname}" \
    'hydra.job.config.override_dirname.exclude_keys=[policy,env,episodes,threads,planner.min_range,planner.time_budget,planner.max_nodes]'
done

if [[ -n "${RUN_PHASE[tables]:-}" ]]; then
  phase "tables: the evaluations' statistics per map against ARVI"
  for map in $MAPS; do
    # at least 4 runs per group (the IQM's least): with fewer, the line that says so, and the script goes on
    if run aia-log stats "$OUT/evals/$map" --group-by trained_env.map --group-by trained_env.features.local_map \
        --group-by algo --group-by exploration --baseline "$OUT/arvi/$map" \
        --baseline-label "ARVI, min range $ARVI_MIN_RANGE m" > "$OUT/tables/$map.md"; then
      echo "-- on $map"
      cat "$OUT/tables/$map.md"
    else
      rm -f "$OUT/tables/$map.md"
      echo "no table for $map: the line above says why"
    fi
  done
fi
phase ""
machine_speed end
echo "done in $(( $(date +%s) - start )) s (each phase's in $OUT/wall_time.tsv); tables in $OUT/tables"
