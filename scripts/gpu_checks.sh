#!/usr/bin/env bash
# The checks a GPU session runs, in one call, in the order of what matters most: an op-by-op profile of a
# population's steady steps eager and compiled (benchmarks/step_profile.py: why compiled CUDA jobs ran slower
# than eager ones on an H200), the eager population rows with a count of the loop's host-device syncs, the
# compiled rows (with dynamo's recompile and graph-break log), the quick start and a population sweep with
# device=cuda; STEPS=envs instead measures the env's CUDA rows of the belief filters and the maps (issues 43 and 44:
# kf, the UKFs, the particle filter; obstacles1, random_obstacles, ttenv_v4), compiled at 4,096 and 65,536 worlds.
# STEPS picks some of them (a device command may run 10 minutes at most). Each step has
# its own time limit and writes its log (and the benchmarks their JSON) under $OUT as it goes, so a run cut short
# keeps what it measured; the last lines printed are each step's table or summary.
#
#   scripts/gpu_checks.sh                                   # on a machine with CUDA and aia installed
#   WHEELS=.whl scripts/gpu_checks.sh                       # install carried wheels and aia first (no network)
#
# Environment variables (defaults in brackets):
#   OUT        output folder [outputs/gpu_checks]
#   DEVICE     torch device [cuda]
#   WHEELS     a folder of wheels to install (with aia from this checkout) into $OUT/site first []
#   EAGER_P / COMPILED_P   population sizes of the eager and compiled rows [1,20,80,320 / 1,20,320]
#   ALGOS      learner rows of benchmarks/population.py [dqn,adfq]; conv adds the ttenv_v4 conv learner
#   STEPS      the steps to run, comma-separated [profile,eager,compiled,quickstart,sweep]; or envs
#   PROFILE_ALGO PROFILE_P   the profiled population [dqn, 80]
#   PROFILE_S EAGER_S COMPILED_S QUICKSTART_S SWEEP_S ENVS_S   each step's limit in seconds [150 240 420 60 60 540]; a
#              compiled size takes about a minute per learner on an H200's host (its first compile and set-up)
set -uo pipefail

OUT=${OUT:-outputs/gpu_checks}
DEVICE=${DEVICE:-cuda}
EAGER_P=${EAGER_P:-1,20,80,320}
COMPILED_P=${COMPILED_P:-1,20,320}
ALGOS=${ALGOS:-dqn,adfq}
STEPS=${STEPS:-profile,eager,compiled,quickstart,sweep}
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
ROOT=$(cd "$(dirname "$0")/.." && pwd)
export PYTHONUNBUFFERED=1
start=$(date +%s)
stamp() { echo "[$(( $(date +%s) - start )) s] $*"; }
quiet() { grep -v -E "frame/s|it/s\]|Warning|warn\(|USDT" || true; }
step() { [[ ",$STEPS," == *",$1,"* ]]; }
ALL_STEPS=profile,eager,compiled,quickstart,sweep,envs
for name in ${STEPS//,/ }; do
  if [[ ",$ALL_STEPS," != *",$name,"* ]]; then
    echo "gpu_checks.sh: STEPS=$STEPS: expected a comma-separated subset of $ALL_STEPS" >&2
    exit 2
  fi
done

if [ -n "${WHEELS:-}" ]; then  # the wheels first, then aia beside them (its hydra_plugins joins theirs)
  python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target "$OUT/site" "$WHEELS"/*.whl || exit 1
  python3 -m pip install -q --no-index --no-deps --no-build-isolation --no-compile --target "$OUT/site-aia" \
    "$ROOT" > /dev/null 2>&1 || exit 1
  export PYTHONPATH="$OUT/site-aia:$OUT/site${PYTHONPATH:+:$PYTHONPATH}" PATH="$OUT/site-aia/bin:$PATH"
fi
if ! python3 -c "
import sys, torch
device = torch.device('$DEVICE')
sys.exit(device.type != 'cuda' or not torch.cuda.is_available() or (device.index or 0) >= torch.cuda.device_count())
" 2> /dev/null; then
  echo "gpu_checks.sh: DEVICE=$DEVICE: not a CUDA device this machine has (cuda, cuda:0, ...); run it where torch sees a GPU" >&2
  exit 2
fi
{ nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv 2>/dev/null
  python3 -c "import sys, torch, tensordict, torchrl; print(sys.version.split()[0], torch.__version__, tensordict.__version__, torchrl.__version__)"
} 2>&1 | tee "$OUT/machine.txt"

if step profile; then
  stamp "profile of ${PROFILE_ALGO:-dqn} x ${PROFILE_P:-80}, eager and compiled"
  timeout "${PROFILE_S:-150}" python3 "$ROOT/benchmarks/step_profile.py" --device "$DEVICE" \
    --algo "${PROFILE_ALGO:-dqn}" --members "${PROFILE_P:-80}" --traces "$OUT/traces" --out "$OUT/step_profile.json" \
    > "$OUT/profile.log" 2>&1
  echo "exit $?" >> "$OUT/profile.log"
  quiet < "$OUT/profile.log" | grep -v -E "^\[|^ *$" | tail -45
fi

if step eager; then
  stamp "eager rows and host syncs"
  timeout "${EAGER_S:-240}" python3 "$ROOT/benchmarks/population.py" --device "$DEVICE" --count-syncs 4 --algos "$ALGOS" \
    --modes eager --members "$EAGER_P" --out "$OUT/population_eager.json" > "$OUT/eager.log" 2>&1
  echo "exit $?" >> "$OUT/eager.log"
  quiet < "$OUT/eager.log" | grep -E "^(dqn|adfq) |syncs of|^ +[0-9]+  |exit" | head -60
fi

if step compiled; then
  stamp "compiled rows"
  TORCH_LOGS=recompiles,graph_breaks timeout "${COMPILED_S:-420}" python3 "$ROOT/benchmarks/population.py" \
    --device "$DEVICE" --algos "$ALGOS" --modes compiled --members "$COMPILED_P" --out "$OUT/population_compiled.json" \
    > "$OUT/compiled.log" 2>&1
  echo "exit $?" >> "$OUT/compiled.log"
  quiet < "$OUT/compiled.log" | grep -E "^(dqn|adfq) |Recompiling|Graph break|Error|exit" | head -30
fi

if step quickstart; then
  stamp "quick start"
  (cd "$OUT" && timeout "${QUICKSTART_S:-60}" aia-train device="$DEVICE" frames=2000 hydra.run.dir="$OUT/quickstart" \
    > "$OUT/quickstart.log" 2>&1; echo "exit $?" >> "$OUT/quickstart.log"
    aia-log summary "$OUT/quickstart/run.mcap" >> "$OUT/quickstart.log" 2>&1)
  quiet < "$OUT/quickstart.log" | grep -E "frames,|time:|eval/score|exit"
fi

if step sweep; then
  stamp "population sweep"
  (cd "$OUT" && timeout "${SWEEP_S:-60}" aia-train -m seed=0,1,2,3 lr=1e-3,5e-4 device="$DEVICE" frames=2000 \
    hydra/launcher=population hydra.sweep.dir="$OUT/sweep" > "$OUT/sweep.log" 2>&1; echo "exit $?" >> "$OUT/sweep.log")
  quiet < "$OUT/sweep.log" | grep -E "population|exit" | tail -6
fi

if step envs; then
  stamp "env rows: belief filters and maps, compiled"
  timeout "${ENVS_S:-540}" python3 "$ROOT/benchmarks/env_throughput.py" --device "$DEVICE" --modes compiled \
    --batch-sizes 4096 65536 --settings empty1 ttenv_v2 ttenv_v3 "ttenv_v2:belief.filter=particle,belief.particles=256" \
    "ttenv_v2:belief.filter=particle,belief.particles=1024" obstacles1 random_obstacles ttenv_v4 \
    --out "$OUT/env_throughput.json" > "$OUT/envs.log" 2>&1
  echo "exit $?" >> "$OUT/envs.log"
  quiet < "$OUT/envs.log" | grep -E "^\||exit" | tail -20
fi
stamp "done"
