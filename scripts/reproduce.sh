#!/usr/bin/env bash
# Reproduce the paper's comparison (SPEC 11): for each setting, DQN, Double DQN, ADFQ-egreedy and ADFQ-TS with
# 5 seeds each, ARVI with 10 seeds, then the Fig. 2 curves (from 4 seeds on, the IQM over runs with its bootstrap
# CI band; with fewer, the mean +-1 std), a results table, the statistics and verdicts of
# aia-log stats ($FIGURES/<setting>_stats.md, from 4 seeds per learner on) and a Fig. 3-style trajectory
# picture of a learned ADFQ-TS policy. Everything is logged to MCAP under $OUT; each phase prints its wall time
# and appends it to $OUT/wall_time.tsv, and the machine's float32 matmul rate at the start and at the end goes to
# $OUT/machine.tsv (GFLOP/s, python3 -m aia.runtime.timing): a shared VM's speed swings, and wall times compare only
# with it.
#
#   scripts/reproduce.sh                                  # the whole protocol (hours on a laptop CPU)
#   SETTINGS="empty1" SEEDS=0,1 FRAMES=2000 ARVI_SEEDS=0,1 scripts/reproduce.sh   # a quick smoke run
#   SEEDS=0-19 ARVI_SEEDS=0-19 ARVI_NODES=25000 scripts/reproduce.sh   # 20 seeds per learner and per ARVI baseline
#
# Environment variables (defaults in brackets):
#   SETTINGS     settings to run [empty1 obstacles1 small2 small3]
#   SEEDS        learner seeds [0,1,2,3,4];  ARVI_SEEDS  planner seeds [0,...,9]; both take ranges too:
#                SEEDS=0-19 is 0,1,...,19, and SEEDS=0-4,10,12-13 mixes both
#   FRAMES       override of each paper experiment's training length [the preset's: 200 training episodes]
#   TRAIN_OVERRIDES  more aia-train overrides, space-separated, e.g. "device=cuda" or "compile.update=false" [];
#                "resume=auto" continues a stopped protocol (below) in the same folders: its learners from their
#                checkpoints, and the ARVI seeds it had not finished (no eval.json) evaluated again from the start
#   JOBS         populations in parallel [2] (one aia-train -m over all settings, hydra/launcher=population:
#                per setting, DQN with Double DQN and ADFQ-egreedy with ADFQ-TS each train all their seeds as one
#                population, the largest populations first);  OUT  output folder [outputs/repro]
#   FIGURES      where the figures and tables go [$OUT/figures]
#   LAUNCHER     where the learners and ARVI run [population]: population (this machine, $JOBS processes) or
#                population_slurm (a SLURM cluster: each learner population one task of a job array,
#                hydra/launcher=population_slurm, and each ARVI seed one SLURM job, hydra/launcher=slurm; the
#                figures are drawn here); give their resources in SLURM_OVERRIDES, e.g.
#                SLURM_OVERRIDES="hydra.launcher.partition=cpu hydra.launcher.cpus_per_task=4" (keys both launchers
#                have: partition, cpus_per_task, mem_gb, timeout_min, gpus_per_node) and TRAIN_OVERRIDES="threads=4"
#   METHODS      learners [dqn,ddqn,adfq_egreedy,adfq_ts] (conf/method/)
#   PHASES       which phases run [learners,arvi,figures]: e.g. PHASES=figures redraws the figures and tables from
#                the runs already in $OUT, PHASES=learners,arvi leaves the drawing to a later call
#   ARVI_EPISODES  episodes per ARVI seed, planned together in one batch [5]
#   ARVI_BUDGET  wall-clock seconds per plan [1.0, the reference's], shared by a seed's episodes; each seed
#                plans in its own process, $JOBS at a time
#   ARVI_NODES   if set, a deterministic budget of this many nodes per world instead of ARVI_BUDGET
#                (25000 is about what one world's 1 s search generates on a 2-core laptop CPU); the seeds then
#                plan in $JOBS processes (hydra/launcher=population, split_to_fill), each seed a budget group
#                of its own, so each seed's results equal those of its own aia-eval run
#   ARVI_MIN_RANGES  planner.min_range values, one ARVI baseline each [0 2]: 0 is ARVI as specified,
#                2 keeps the plan off the belief mean (docs/planner.md, "Minimum planning range");
#                ARVI_MIN_RANGES= (empty) runs no ARVI, e.g. to add learner seeds
# Set but empty, ARVI_MIN_RANGES means no ARVI, and FRAMES, ARVI_NODES, TRAIN_OVERRIDES and SLURM_OVERRIDES mean
# what unset does; any other variable set but empty (SEEDS=, say, or SEEDS=$TYPO) is refused in one line naming it
# and what it takes, as a bad value is (exit 2), before anything runs.
#
# Stopping. SIGINT (Ctrl-C), SIGTERM (kill PID, timeout) or SIGUSR1 to this script go on, once each, to every
# process of the sweep or job it is running (SIGHUP goes on as SIGTERM): each running population ends its episode
# and writes its checkpoints (a second Ctrl-C kills them instead), ARVI, evaluations and figures end at once. The
# script waits for them (the rest of an episode), then exits with 128 + signal (130, 143) and one line: continue it with
# TRAIN_OVERRIDES="resume=auto" and the other variables as they were. A sweep stopped by a signal sent to it alone
# (SIGTERM or SIGUSR1 to its launcher) ends the script the same way. Under LAUNCHER=population_slurm the SLURM jobs
# go on (the launcher's line names them: scancel them before continuing). SIGKILL (kill -9, timeout -k) cannot be
# passed on: the running sweep would go on without the script.
#
# Each run's folder is named by what varies (e.g. $OUT/empty1/learners/method=adfq_ts,seed=3), so a later call
# with more seeds or methods adds runs next to the ones already there. A run folder is never trained or evaluated
# over: give a later call only the new seeds (ARVI_MIN_RANGES= skips ARVI), or TRAIN_OVERRIDES="resume=auto",
# with which the learner runs already there continue (a finished run stays as it is) and the ARVI runs already
# finished are kept.
set -euo pipefail
# given, given_some, train_extras, seed_list, parse_phases, unfinished, resuming, machine_speed, phase, run, job, throttle, drain; the stop signals' trap
# shellcheck source-path=SCRIPTDIR source=lib/protocol.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib/protocol.sh"

# Everything is checked before anything runs: a bad or empty value ends the script in one line (exit 2).
given_some SETTINGS "empty1 obstacles1 small2 small3" setting
given SEEDS 0,1,2,3,4 "seeds, e.g. 0,1,2 or 0-19 or 0-4,10"
given ARVI_SEEDS 0,1,2,3,4,5,6,7,8,9 "seeds, e.g. 0,1,2 or 0-19 or 0-4,10 (ARVI_MIN_RANGES= for no ARVI)"
given JOBS 2 "a number of processes"
given OUT outputs/repro "a folder"
given FIGURES "$OUT/figures" "a folder"
given ARVI_EPISODES 5 "a number of episodes"
given ARVI_BUDGET 1.0 "seconds per plan"
given METHODS dqn,ddqn,adfq_egreedy,adfq_ts "some of conf/method/, comma-separated"
given LAUNCHER population "population or population_slurm"
given PHASES learners,arvi,figures "some of learners,arvi,figures"
ARVI_MIN_RANGES=${ARVI_MIN_RANGES-"0 2"}  # set but empty: no ARVI runs
whole_number JOBS
read -r -a SLURM_EXTRA <<< "${SLURM_OVERRIDES:-}"
case "$LAUNCHER" in
  population)
    LEARNER_LAUNCHER=(hydra/launcher=population "hydra.launcher.n_jobs=$JOBS")
    if [[ -n "${ARVI_NODES:-}" ]]; then
      # a node budget is each seed's own in a batch: all seeds in $JOBS processes
      ARVI_LAUNCHER=(hydra/launcher=population hydra.launcher.split_to_fill=true "hydra.launcher.n_jobs=$JOBS")
    else
      # a wall-clock budget is shared by everything planned together: one process per seed
      ARVI_LAUNCHER=(hydra/launcher=local "hydra.launcher.n_jobs=$JOBS")
    fi ;;
  population_slurm)
    stop_note=" (the SLURM jobs go on: scancel the ones the launcher's line above names first)"
    LEARNER_LAUNCHER=(hydra/launcher=population_slurm "${SLURM_EXTRA[@]}")
    ARVI_LAUNCHER=(hydra/launcher=slurm "${SLURM_EXTRA[@]}")  # one job per seed, whatever the budget
    ;;
  *)
    echo "LAUNCHER='$LAUNCHER': expected population or population_slurm" >&2
    exit 2 ;;
esac
# shellcheck disable=SC2153  # given sets SEEDS
SEED_LIST=$(seed_list SEEDS "$SEEDS")
# The curves' bands: from 4 seeds per learner on (the IQM's least), the IQM over runs and its stratified-bootstrap
# CI at each point, as the statistics' verdicts; with fewer, +-1 std over runs.
BANDS=(--ci std)
if (( $(tr ',' '\n' <<< "$SEED_LIST" | wc -l) >= 4 )); then BANDS=(--ci bootstrap); fi
ARVI_SEED_LIST=$(seed_list ARVI_SEEDS "$ARVI_SEEDS")
parse_phases "$PHASES" learners arvi figures
if [[ -n "${ARVI_NODES:-}" ]]; then
  ARVI_BUDGET_OVERRIDES=("planner.time_budget=null" "planner.max_nodes=$ARVI_NODES")
else
  ARVI_BUDGET_OVERRIDES=("planner.time_budget=$ARVI_BUDGET")
fi
train_extras

declare -A WHERE=(
  [empty1]="--where env.map=empty"
  [obstacles1]="--where env.map=obstacles4"
  [small2]="--where env.map=empty_small --where env.num_targets=2"
  [small3]="--where env.map=empty_small --where env.num_targets=3"
)
mkdir -p "$OUT" "$FIGURES"
machine_speed start
start=$(date +%s)
phase_start=$start
read -r -a SETTING_LIST <<< "$SETTINGS"
joined() { local IFS=,; echo "$*"; }
EXPERIMENTS=$(joined "${SETTING_LIST[@]/#/paper_}")
OUT_ABS=$(cd "$OUT" && pwd)
# Each sweep keeps its multirun.yaml in $OUT/sweeps/<name>; its runs go to $OUT/<setting>/<name>/<what varies>
# (an absolute hydra.sweep.subdir: Hydra joins it to the sweep folder as os.path.join does, i.e. it is kept).
run_dir() { echo "hydra.sweep.subdir=$OUT_ABS/\${hydra:runtime.choices.env}/$1/\${hydra.job.override_dirname}"; }
# baseline MIN_RANGE: set name (the ARVI runs' folder) and label (their name in figures) of that minimum range
baseline() {
  name=arvi; label=ARVI
  if [[ "$1" != "0" ]]; then name="arvi_min$1"; label="ARVI, min range $1 m"; fi
}

# One sweep of every setting's learners: DQN with Double DQN and ADFQ-egreedy with ADFQ-TS share a program
# (aia/training/members.py), so each setting trains two populations of 2 x seeds members; the launcher starts
# the largest populations first, $JOBS at a time.
if [[ -n "${RUN_PHASE[learners]:-}" ]]; then
  phase "learners: $SETTINGS x $METHODS x seeds $SEEDS, as populations ($LAUNCHER)"
  run aia-train -m "${LEARNER_LAUNCHER[@]}" "experiment=$EXPERIMENTS" "method=$METHODS" "seed=$SEED_LIST" threads=1 \
    "${FRAMES_OVERRIDE[@]}" "${TRAIN_EXTRA[@]}" "hydra.sweep.dir=$OUT/sweeps/learners" \
    "$(run_dir learners)" \
    'hydra.job.config.override_dirname.exclude_keys=[experiment,threads,frames,device,resume,compile.update,compile.env,compile.policy]'
fi
for min_range in ${RUN_PHASE[arvi]:+$ARVI_MIN_RANGES}; do
  baseline "$min_range"
  phase "$label: $SETTINGS x seeds $ARVI_SEEDS"
  # the seeds still to evaluate -> the settings that need them: one sweep, or after a stop (resume=auto) one per
  # set of seeds that the settings' finished runs leave
  declare -A PENDING=()
  for setting in "${SETTING_LIST[@]}"; do
    pending_seeds=$ARVI_SEED_LIST
    if resuming; then pending_seeds=$(unfinished "$OUT/$setting/$name" "$ARVI_SEED_LIST"); fi
    if [[ -n "$pending_seeds" ]]; then PENDING[$pending_seeds]+="${PENDING[$pending_seeds]:+,}$setting"; fi
  done
  if (( ${#PENDING[@]} == 0 )); then echo "-- every run is there already"; fi
  for pending_seeds in "${!PENDING[@]}"; do
    run aia-eval -m "${ARVI_LAUNCHER[@]}" policy=arvi "env=${PENDING[$pending_seeds]}" "seed=$pending_seeds" \
      "episodes=$ARVI_EPISODES" threads=1 "planner.min_range=$min_range" "${ARVI_BUDGET_OVERRIDES[@]}" \
      "hydra.sweep.dir=$OUT/sweeps/$name" "$(run_dir "$name")" \
      'hydra.job.config.override_dirname.exclude_keys=[policy,env,episodes,threads,planner.min_range,planner.time_budget,planner.max_nodes]'
  done
  unset PENDING
done

# figures SETTING: the setting's Fig. 2 curves and results table, and a Fig. 3-style trajectory of its first
# ADFQ-TS seed (its output in $FIGURES/SETTING.log)
figures() {
  local setting=$1 baselines=() min_range name label config learner
  for min_range in $ARVI_MIN_RANGES; do
    baseline "$min_range"
    baselines+=(--baseline "$OUT/$setting/$name" --baseline-label "$label")
  done
  # shellcheck disable=SC2086  # WHERE holds several words on purpose
  aia-log plot "$OUT/$setting/learners" ${WHERE[$setting]} --group-by algo --group-by exploration --x episode \
    --window 4 "${baselines[@]}" "${BANDS[@]}" --title "$setting" --out "$FIGURES/$setting.png" \
    | tee "$FIGURES/$setting.md"
  # the verdicts (docs/RESULTS.md, "How verdicts are decided"): IQM and mean with bootstrap CIs, and per baseline
  # the probability of improvement, the difference, the verdict and the episode reaching it; at least 4 seeds
  # shellcheck disable=SC2086
  if ! aia-log stats "$OUT/$setting/learners" ${WHERE[$setting]} --group-by algo --group-by exploration \
      --x episode --window 4 "${baselines[@]}" > "$FIGURES/${setting}_stats.md"; then
    rm -f "$FIGURES/${setting}_stats.md"
    echo "no statistics for $setting: the line above says why"
  fi
  config=$(grep -l "thompson" "$OUT/$setting"/learners/*/.hydra/config.yaml | head -1 || true)
  if [[ -z "$config" ]]; then echo "no ADFQ-TS run in $OUT/$setting/learners: no trajectory picture"; return; fi
  learner=$(dirname "$(dirname "$config")")
  # A trajectory evaluated from this checkpoint already (a second PHASES=figures) is drawn again as it is; one
  # older than the checkpoint, or stopped before its end (no eval.json), is evaluated again (run logs are never
  # overwritten: its folder goes first).
  if [[ ! -f "$OUT/$setting/trajectory/eval.json" || ! "$OUT/$setting/trajectory/run.mcap" -nt \
        "$learner/checkpoints/last.pt" ]]; then
    rm -rf "$OUT/$setting/trajectory"
    # quoted: the run's folder name holds '=' and ',' (method=adfq_ts,seed=0), which Hydra's grammar reserves
    aia-eval "checkpoint='$learner/checkpoints/last.pt'" episodes=5 seed=0 threads=1 \
      "hydra.run.dir=$OUT/$setting/trajectory"
  fi
  aia-log render "$OUT/$setting/trajectory/run.mcap" --episode first --frames 5 --size 320 \
    --out "$FIGURES/${setting}_trajectory.png"
}
if [[ -n "${RUN_PHASE[figures]:-}" ]]; then
  phase "figures: Fig. 2 curves, results tables and Fig. 3-style trajectories, $JOBS settings at a time"
  for setting in $SETTINGS; do
    job figures "$setting" > "$FIGURES/$setting.log" 2>&1
    throttle
  done
  drain
  for setting in $SETTINGS; do echo "-- $setting"; cat "$FIGURES/$setting.log"; done
  if (( failed )); then echo "a setting's figures failed (its output above)" >&2; exit 1; fi
fi
phase ""
machine_speed end
echo "done in $(( $(date +%s) - start )) s (each phase's in $OUT/wall_time.tsv); figures and tables in $FIGURES"
