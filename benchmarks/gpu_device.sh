#!/bin/bash
# One prepared call on a lent GPU machine (the device tool's `run`, with carry [".whl"]): the GPU
# engine's tests on the hardware, then its throughput against batch size beside the CPU kernel.
# Everything it prints also goes under $OUT. Never run yet: its time is a guess (the two steps are capped at
# 200 s and 300 s); give it timeout_s 540.
# .whl holds what the machine's image lacks, tomli-w (the image has numba-cuda and the rest); make it here,
# once, in the repository's root (it is not committed):
#   echo /.whl/ >> .git/info/exclude
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux_2_28_x86_64 -d .whl tomli-w==1.2.0
set -o pipefail
export PYTHONUNBUFFERED=1 NUMBA_ENABLE_CUDASIM=0
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
if ls .whl/*.whl >/dev/null 2>&1; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=$PWD:/tmp/site
else
  export PYTHONPATH=$PWD
fi
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv | tee "$OUT/gpu.txt"
python3 -c "import numba, numba.cuda as c; print('numba', numba.__version__, 'cuda target', getattr(c, 'implementation', '?'))" \
  | tee -a "$OUT/gpu.txt"
timeout 200 python3 -m pytest -q -p no:cacheprovider -m "not slow" tests/test_gpu.py 2>&1 | tail -25 | tee "$OUT/test_gpu.log"
timeout 300 python3 benchmarks/gpu_throughput.py --batches 1,4,16,64 --paper-batches 1 --steps 1000 --warmup 100 \
  2>&1 | tee "$OUT/throughput.log"
