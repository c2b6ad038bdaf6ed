#!/usr/bin/env bash
# The GPU check: engines, CNN training throughput, fit's wall time and the samplers with MJX on a CUDA GPU.
#
# Never part of CI (which has no GPU). Run from the repository root on a machine with a CUDA build
# of JAX (0.10-0.11) whose other packages are installed or, where pip cannot reach an index, laid
# out as wheels in .whl/ (on an image with JAX, Flax, optax and optimistix but no MuJoCo: mujoco,
# mujoco-core, mujoco-studio, mujoco-mjx, glfw, pyopengl, trimesh, arviz, xarray-einstats, h5netcdf,
# platformdirs, cma, pydantic, pydantic-core, annotated-types, typing-inspection, typing-extensions;
# docs/gpu.md has the measurements). Each step has its own time limit and writes its tables as it goes, so a step
# that fails or runs out of time leaves the others' results:
#
#   engines         benchmarks/results/engines_gpu.{md,json}         MJX vs C MuJoCo rollouts/s
#   engines_cmdbuf  benchmarks/results/engines_gpu_cmdbuf.{md,json}  the same with XLA's CUDA-graph command
#                   buffers extended to loops and conditionals (CMDBUF_FLAGS below; batch sizes 1 and 256)
#   cnn             benchmarks/results/cnn_throughput_gpu.{md,json}  training examples/s
#   fit             benchmarks/results/fit_timing_gpu.{md,json}      README command 1 (grad, mh) cold and warm
#   samplers        benchmarks/results/samplers_gpu.{md,json}        the samplers benchmark on MJX: one pre-rendered
#                   ramp_20 video (render it on a machine with EGL first, see docs/gpu.md), mh shortened to
#                   100 + 100 steps; with CMDBUF_FLAGS when engines_cmdbuf measured them faster at batch 1
#   tests           the physics closed forms and the two engines' agreement, on the GPU
#
#   bash benchmarks/gpu_check.sh [seconds] [steps]   # total time limit (default 540), comma-separated steps
#                                                    # (default engines,cnn,fit,tests)
set -u
START=$(date +%s)
LIMIT=${1:-540}
STEPS=,${2:-engines,cnn,fit,tests},
CMDBUF_FLAGS="--xla_gpu_enable_command_buffer=FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,WHILE,CONDITIONAL"
left() { echo $((START + LIMIT - $(date +%s))); }
# MuJoCo's renderer is not needed here (and without libEGL its import fails): MUJOCO_GL=disable
export PYTHONUNBUFFERED=1 MUJOCO_GL=${MUJOCO_GL:-disable} XLA_PYTHON_CLIENT_PREALLOCATE=false
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}
if [ -d .whl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || exit 1
  export PYTHONPATH=/tmp/site:$PYTHONPATH
fi
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c "import jax, mujoco; from mujoco import mjx; print('jax', jax.__version__, jax.devices(), 'mujoco', mujoco.__version__)" \
  || exit 1
step() {  # step NAME SECONDS COMMAND...
  local name=$1 secs=$2; shift 2
  case $STEPS in *,$name,*) ;; *) return ;; esac
  [ "$secs" -gt "$(left)" ] && secs=$(left)
  [ "$secs" -lt 30 ] && { echo "== $name: skipped, $(left) s left"; return; }
  echo "== $name (limit $secs s)"
  local t0; t0=$(date +%s)
  timeout "$secs" "$@"
  echo "== $name: exit $?, $(( $(date +%s) - t0 )) s"
}
R=benchmarks/results
# ENGINE_BATCHES (default 1,256,4096); with a committed engines_gpu.json only those rows are measured again (--merge)
[ -f $R/engines_gpu.json ] && MERGE=--merge || MERGE=
step engines 250 python3 benchmarks/engines.py --batches "${ENGINE_BATCHES:-1,256,4096}" --repeats 3 $MERGE --out engines_gpu
if [ -f $R/engines_gpu.json ]; then
  # the default flags' table as the starting point without its rows: its compile times are kept (--merge)
  python3 -c "import json; t = json.load(open('$R/engines_gpu.json')); t['rows'] = []; t['command'] = 'XLA_FLAGS=$CMDBUF_FLAGS'
json.dump(t, open('$R/engines_gpu_cmdbuf.json', 'w'))"
fi
step engines_cmdbuf 120 env XLA_FLAGS="$CMDBUF_FLAGS" \
  python3 benchmarks/engines.py --batches 1,256 --repeats 3 --merge --out engines_gpu_cmdbuf
step cnn 170 python3 benchmarks/cnn_throughput.py --engines mjx,mujoco --rollouts 32,1024 --steps 10 --out cnn_throughput_gpu
step fit 300 python3 benchmarks/fit_timing.py --methods grad mh --out fit_timing_gpu
FASTER=$(python3 - <<'PY' 2>/dev/null
import json
rate = lambda n: {r["batch"]: r["mjx_rollouts_per_s"] for r in json.load(open(f"benchmarks/results/{n}.json"))["rows"]}[1]
print(int(rate("engines_gpu_cmdbuf") > 1.2 * rate("engines_gpu")))
PY
)
echo "command buffers faster at batch 1: ${FASTER:-unknown}"
[ "${FASTER:-0}" = 1 ] && SFLAGS=$CMDBUF_FLAGS || SFLAGS=${XLA_FLAGS:-}
step samplers 330 env XLA_FLAGS="$SFLAGS" python3 benchmarks/samplers.py --videos 1 --scenes ramp_20 --engine mjx \
  --mh-warmup 100 --mh-samples 100 --out $R/samplers_gpu
step tests 120 python3 -m pytest -q -p no:cacheprovider -n 4 tests/test_physics.py tests/test_engines.py
