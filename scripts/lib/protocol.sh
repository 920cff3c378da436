# shellcheck shell=bash
# Shell functions of the experiment protocols (scripts/reproduce.sh, scripts/generalisation.sh), sourced by them
# first thing. They read the protocol's $OUT, $JOBS and $TRAIN_OVERRIDES, and keep their state in globals
# (phase_name, phase_start; running, failed; stop_signal). Sourcing this file installs the stop signals' trap.

# given NAME DEFAULT WHAT: NAME keeps its value, or becomes DEFAULT where it is unset; set but empty, it is refused in
# one line saying that it takes WHAT (exit 2): an empty value is a slip (SEEDS=$UNSET, SEEDS= ...), not a request for
# the default, which may be far bigger than meant.
given() {
  if [[ -z "${!1+set}" ]]; then
    printf -v "$1" '%s' "$2"
  elif [[ -z "${!1}" ]]; then
    echo "$1 is empty: expected $3, or unset for $2" >&2
    exit 2
  fi
}

# given_some NAME ALLOWED WHAT: as given, NAME defaulting to all of ALLOWED (words); a word of $NAME that is not one
# of them is refused in one line naming it, a WHAT, and ALLOWED (exit 2)
given_some() {
  local item
  given "$1" "$2" "some of $2"
  for item in ${!1}; do
    if [[ " $2 " != *" $item "* ]]; then
      echo "$1: unknown $3 '$item'; expected some of $2" >&2
      exit 2
    fi
  done
}

# train_extras: what the protocol adds to every aia-train command, FRAMES_OVERRIDE (frames=$FRAMES where FRAMES is
# set and not empty) and TRAIN_EXTRA ($TRAIN_OVERRIDES, word by word)
# shellcheck disable=SC2034  # the protocol scripts read them
train_extras() {
  FRAMES_OVERRIDE=()
  if [[ -n "${FRAMES:-}" ]]; then FRAMES_OVERRIDE=("frames=$FRAMES"); fi
  read -r -a TRAIN_EXTRA <<< "${TRAIN_OVERRIDES:-}"
}

# whole_number NAME: exit 2 unless $NAME is a whole number from 1 on
whole_number() {
  if [[ ! "${!1}" =~ ^[1-9][0-9]*$ ]]; then echo "$1='${!1}': expected a whole number from 1 on" >&2; exit 2; fi
}

# seed_list NAME VALUE: VALUE's seeds and ranges (0-19, 0-4,10) as a comma-separated list; exit 2 naming a bad one
seed_list() {
  local item seeds=() k
  local IFS=,
  for item in $2; do
    if [[ "$item" =~ ^[0-9]+$ ]]; then
      seeds+=("$((10#$item))")
    elif [[ "$item" =~ ^([0-9]+)-([0-9]+)$ ]] && (( 10#${BASH_REMATCH[1]} <= 10#${BASH_REMATCH[2]} )); then
      for (( k = 10#${BASH_REMATCH[1]}; k <= 10#${BASH_REMATCH[2]}; k++ )); do seeds+=("$k"); done
    else
      echo "$1='$2': '$item' is not a seed or a rising range; expected e.g. 0,1,2 or 0-19 or 0-4,10" >&2
      exit 2
    fi
  done
  if (( ${#seeds[@]} == 0 )); then echo "$1='$2': no seeds; expected e.g. 0,1,2 or 0-19 or 0-4,10" >&2; exit 2; fi
  echo "${seeds[*]}"
}

# parse_phases VALUE PHASE...: RUN_PHASE[p]=1 for each phase p that VALUE (comma-separated) names; exit 2 naming
# a phase that is not one of PHASE...
parse_phases() {
  local value=$1 item allowed
  shift
  allowed=$(IFS=,; echo "$*")
  declare -gA RUN_PHASE=()
  IFS=, read -r -a PHASE_LIST <<< "$value"
  for item in "${PHASE_LIST[@]}"; do
    if [[ " $* " != *" $item "* ]]; then
      echo "PHASES='$value': '$item' is not a phase; expected some of $allowed" >&2
      exit 2
    fi
    RUN_PHASE[$item]=1
  done
  if (( ${#RUN_PHASE[@]} == 0 )); then echo "PHASES='$value': no phase; expected some of $allowed" >&2; exit 2; fi
}

# unfinished DIR SEEDS: those of SEEDS (comma-separated) whose run DIR/seed=<seed> has not finished (it has no
# eval.json), comma-separated; their folders, a stopped call's partial runs, are removed (a run log is never
# written over)
unfinished() {
  local seed todo=()
  local IFS=,
  for seed in $2; do
    if [[ -f "$1/seed=$seed/eval.json" ]]; then continue; fi
    rm -rf "$1/seed=$seed"
    todo+=("$seed")
  done
  echo "${todo[*]}"
}

# machine_speed WHEN: record the machine's matmul rate now in $OUT/machine.tsv (nan if it cannot be measured)
machine_speed() {
  local gflops
  gflops=$(python3 -m aia.runtime.timing 2>/dev/null || echo nan)
  echo "-- machine: sgemm $gflops GFLOP/s ($1)"
  printf 'sgemm_gflops_%s\t%s\n' "$1" "$gflops" >> "$OUT/machine.tsv"
}

phase_name=""
phase_start=$(date +%s)
# phase NAME: end the running phase, print and record its wall time in $OUT/wall_time.tsv, and start NAME
phase() {
  local now
  now=$(date +%s)
  if [[ -n "$phase_name" ]]; then
    echo "-- $phase_name: $(( now - phase_start )) s"
    printf '%s\t%s\n' "$phase_name" "$(( now - phase_start ))" >> "$OUT/wall_time.tsv"
  fi
  phase_name=$1
  phase_start=$now
  if [[ -n "$phase_name" ]]; then echo "== $phase_name"; fi
}

# Stopping. Every command that runs for long (a sweep, an evaluation, a setting's figures) starts as a job (job, run
# below): in the background, where bash runs a trap at once rather than after the command, and as a process group
# of its own, which the script waits for. SIGINT, SIGTERM and SIGUSR1 to the script (Ctrl-C, kill PID, timeout;
# SIGHUP, a closed terminal, as SIGTERM) go on to every running job's whole group, each signal once, as a Ctrl-C
# reaches a command in a terminal: the population launcher's running populations end their episodes and write
# their checkpoints (a second Ctrl-C kills them), an evaluation or a figure ends at once. A group of its own, so
# that a terminal's Ctrl-C reaches a sweep from the script only: one that reached it directly as well would be a
# second Ctrl-C to the launcher. The script waits for its jobs to end, then exits with 128 + signal and one line
# saying how to continue (stopped). A sweep that a signal sent to it alone stopped (SIGTERM or SIGUSR1 to the
# launcher) ends the script the same way. What runs on a stop forks nothing (no command substitution): timeout
# signals the script and then its whole process group, which ends a subshell forked in between at once; a
# `$(jobs -pr)` so ended read as no job, and the script hung, the sweep never told, or left it running (4 of 40
# timeouts of the test on a loaded machine).
job_pids=()  # the jobs not yet waited for (each its process group's leader), which a stop signal goes on to
declare -A signal_number=()
for signal in INT TERM USR1 HUP; do signal_number[$signal]=$(kill -l "$signal"); done
stop_signal=""
stop_note=""  # a script's addition to the line on a stop
# on_stop SIGNAL: the trap of the stop signals; a further Ctrl-C while it waits is forwarded in turn (it kills the
# running populations), a further SIGTERM, SIGUSR1 or SIGHUP adds nothing to the first (timeout signals the script,
# then its process group: twice)
on_stop() {
  local pid forward=$1
  if [[ "$1" == HUP ]]; then forward=TERM; fi
  stop_signal=${stop_signal:-$1}
  for pid in "${job_pids[@]}"; do kill -s "$forward" -- "-$pid" 2>/dev/null || true; done
  while job_running; do wait || true; done
  stopped "$stop_signal"
}
# job_running: whether a job not yet waited for still runs (bash reaps an ended job at once)
job_running() {
  local pid
  for pid in "${job_pids[@]}"; do if kill -0 "$pid" 2>/dev/null; then return 0; fi; done
  return 1
}
# waited PID: job PID was waited for (its process id may now be another process's)
waited() {
  local pid kept=()
  for pid in "${job_pids[@]}"; do if [[ "$pid" != "$1" ]]; then kept+=("$pid"); fi; done
  job_pids=("${kept[@]}")
}
for signal in INT TERM USR1 HUP; do
  # the repeat's test in the trap itself: bash 5.2 cannot return from a function called by a trap that interrupted
  # the same function ("pop_var_context: head of shell_variables not a function context")
  # shellcheck disable=SC2064  # the signal's name, now
  trap "if [[ -z \$stop_signal || $signal == INT ]]; then on_stop $signal; fi" "$signal"
done
unset signal

# resuming: whether TRAIN_OVERRIDES holds resume=auto (a stopped protocol continued)
resuming() {
  local word words
  read -r -a words <<< "${TRAIN_OVERRIDES:-}"
  for word in "${words[@]}"; do if [[ "$word" == resume=auto ]]; then return 0; fi; done
  return 1
}

# stopped SIGNAL: the protocol's one line on a stop (to stderr), then exit with 128 + SIGNAL: TRAIN_OVERRIDES with
# resume=auto continues it (the learners from their checkpoints; the evaluations it had not finished run again)
stopped() {
  local resume="${TRAIN_OVERRIDES:+$TRAIN_OVERRIDES }resume=auto" where=""
  if resuming; then resume=$TRAIN_OVERRIDES; fi
  if [[ -n "$phase_name" ]]; then where=" in phase '${phase_name%%:*}'"; fi
  echo "${0##*/}: stopped by SIG$1$where, its running jobs ended: continue it with" \
    "TRAIN_OVERRIDES=\"$resume\" and the other variables as they were$stop_note" >&2
  exit $(( 128 + signal_number[$1] ))
}

# job CMD...: start CMD in the background as a process group of its own (job control on for this one fork), stdin
# from /dev/null; its process id in $!. A shell function runs in a subshell that a stop signal ends once the
# command it is running has ended (the signal reached that command too), so that it starts none after.
job() {
  set -m
  if declare -F "$1" > /dev/null; then
    (trap 'exit 130' INT; trap 'exit 143' TERM; trap 'exit 138' USR1; "$@") < /dev/null &
  else
    "$@" < /dev/null &
  fi
  set +m
  job_pids+=("$!")
}

# run CMD...: CMD as a job, waited for; its exit status. A sweep ended by a stop signal sent to it alone (status
# 128 + SIGINT, SIGTERM or SIGUSR1) ends the protocol as one sent to the script does.
run() {
  local status=0 pid name
  job "$@"
  pid=$!
  wait "$pid" || status=$?
  waited "$pid"
  for name in INT TERM USR1; do if (( status == 128 + signal_number[$name] )); then stopped "$name"; fi; done
  return "$status"
}

# Background jobs, $JOBS at a time: `job CMD...; throttle` after starting each, `drain` at the end; failed=1 once
# any job has failed.
# shellcheck disable=SC2034  # failed: read by the scripts
running=0 failed=0
throttle() {
  local pid
  running=$(( running + 1 ))
  if (( running >= JOBS )); then wait -n -p pid || failed=1; waited "$pid"; running=$(( running - 1 )); fi
}
# shellcheck disable=SC2034  # failed: read by the scripts
drain() {
  local pid
  while (( running > 0 )); do wait -n -p pid || failed=1; waited "$pid"; running=$(( running - 1 )); done
}
