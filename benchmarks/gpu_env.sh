# Sourced by the prepared GPU calls (gpu_device.sh, gpu_device_layout.sh): the carried wheels installed, the
# output folder, a logger, and the GPU and versions written first to $OUT/gpu.txt. LIMIT: the caller's seconds.
set -o pipefail
export PYTHONUNBUFFERED=1 NUMBA_ENABLE_CUDASIM=0
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
SITE=$PWD
if ls .whl/*.whl >/dev/null 2>&1; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
    .whl/*.whl || exit 1
  SITE=$SITE:/tmp/site
fi
export PYTHONPATH=$SITE
log() { echo "$* at ${SECONDS} s" | tee -a "$OUT/gpu.txt"; }
{ nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv; nproc
  python3 -c "import numba, numpy, numba_cuda, numba.cuda as c; print('numba', numba.__version__, 'numba-cuda', \
numba_cuda.__version__, 'numpy', numpy.__version__, 'gpu', c.is_available())"
} 2>&1 | tee "$OUT/gpu.txt"
