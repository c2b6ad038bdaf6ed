#!/usr/bin/env bash
# The GPU check: engines, CNN training throughput and fit's wall time with MJX on a CUDA GPU.
#
# Never part of CI (which has no GPU). Run from the repository root on a machine with a CUDA build
# of JAX (0.10-0.11) whose other packages are installed or, where pip cannot reach an index, laid
# out as wheels in .whl/ (on an image with JAX, Flax, optax and optimistix but no MuJoCo: mujoco,
# mujoco-core, mujoco-studio, mujoco-mjx, glfw, pyopengl, trimesh, arviz, xarray-einstats, h5netcdf,
# platformdirs, cma, pydantic, pydantic-core, annotated-types, typing-inspection, typing-extensions;
# docs/gpu.md has the measurements). Each step has its own time limit and writes its tables as it goes, so a step
# that fails or runs out of time leaves the others' results:
#
#   benchmarks/results/engines_gpu.{md,json}         MJX vs C MuJoCo rollouts/s (engines.md shows it too)
#   benchmarks/results/cnn_throughput_gpu.{md,json}  training examples/s (cnn_accuracy.md shows it too)
#   benchmarks/results/fit_timing_gpu.{md,json}      README command 1 (grad, mh) cold and warm
#
#   bash benchmarks/gpu_check.sh [seconds]     # total time limit, default 540
set -u
START=$(date +%s)
LIMIT=${1:-540}
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
  [ "$secs" -gt "$(left)" ] && secs=$(left)
  [ "$secs" -lt 30 ] && { echo "== $name: skipped, $(left) s left"; return; }
  echo "== $name (limit $secs s)"
  local t0; t0=$(date +%s)
  timeout "$secs" "$@"
  echo "== $name: exit $?, $(( $(date +%s) - t0 )) s"
}
step engines 250 python3 benchmarks/engines.py --batches 1,256,4096 --repeats 3 --out engines_gpu
step cnn 170 python3 benchmarks/cnn_throughput.py --engines mjx,mujoco --rollouts 32,1024 --steps 10 --out cnn_throughput_gpu
step fit 300 python3 benchmarks/fit_timing.py --methods grad mh --out fit_timing_gpu
# the physics closed forms and the two engines' agreement, on the GPU (whatever time is left)
step tests 120 python3 -m pytest -q -p no:cacheprovider -n 4 tests/test_physics.py tests/test_engines.py
