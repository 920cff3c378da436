# Shell functions of the experiment protocols (scripts/reproduce.sh, scripts/generalisation.sh), sourced by them.
# They read the protocol's $OUT and $JOBS, and keep their state in globals (phase_name, phase_start; running, failed).

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

# Background jobs, $JOBS at a time: `job &; throttle` after starting each, `drain` at the end; failed=1 once any
# job has failed.
running=0 failed=0
throttle() {
  running=$(( running + 1 ))
  if (( running >= JOBS )); then wait -n || failed=1; running=$(( running - 1 )); fi
}
drain() {
  while (( running > 0 )); do wait -n || failed=1; running=$(( running - 1 )); done
}
