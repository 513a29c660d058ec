#!/bin/bash
# One prepared call on a lent GPU machine (the device tool's `run`, carry [".whl"], timeout_s 590), for the
# GPU engine's figures in docs/performance.md: its throughput against batch size beside the CPU kernel on the
# machine's cores; the paper's BBD at the `default` preset and 150 MPa on the GPU (make default-bbd-150mpa's
# design, 34 heaps, against the committed CPU run), the engine's tests on the hardware beside it; then, with
# the time left, the CPU/GPU agreement heaps (benchmarks/gpu_agree.py). Everything goes under $OUT.
# .whl holds what the machine's image lacks (not committed; make it here, in the repository's root):
#   echo /.whl/ >> .git/info/exclude
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux_2_28_x86_64 -d .whl tomli-w==1.2.0 pyDOE3==1.6.2
#   ... -d .whl/nc numba-cuda==0.30.4    # used only where the image's numba-cuda is older than 0.30
# History: 2026-11-26 on an H200 (image: numba 0.68.0, numba-cuda 0.30.4, numpy 2.5.2) the first version of
# this script (throughput, agreement, tests) took 133 s.
set -o pipefail
export PYTHONUNBUFFERED=1 NUMBA_ENABLE_CUDASIM=0
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
LIMIT=${LIMIT:-570}   # seconds for the whole script
SITE=$PWD
if ls .whl/*.whl >/dev/null 2>&1; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
  SITE=$SITE:/tmp/site
fi
export PYTHONPATH=$SITE
if ! python3 -c "import numba_cuda, sys; v = tuple(int(x) for x in numba_cuda.__version__.split('.')[:2]); sys.exit(v < (0, 30))"; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/nc .whl/nc/*.whl && export PYTHONPATH=/tmp/nc:$SITE
fi
{ nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv; nproc
  python3 -c "import numba, numpy, numba_cuda, numba.cuda as c; print('numba', numba.__version__, 'numba-cuda', numba_cuda.__version__, 'numpy', numpy.__version__, 'gpu', c.is_available())"
} 2>&1 | tee "$OUT/gpu.txt"
timeout 150 python3 -W ignore benchmarks/gpu_throughput.py --batches 1,16,64,256 --paper-batches 1 --steps 1000 \
  --warmup 100 --cpu-heaps 1 2>&1 | tee "$OUT/throughput.log"
echo "throughput done at ${SECONDS} s" | tee -a "$OUT/gpu.txt"
timeout 240 nice python3 -m pytest -q -p no:cacheprovider -W ignore tests/test_gpu.py 2>&1 | tail -30 > "$OUT/test_gpu.log" &
RUN=/tmp/bbd150
T0=$SECONDS
# the BBD's slowest heap takes 665,000 steps at 150 MPa: from the 64-heap row's time a step, will it fit?
NEED=$(awk '$1 == "default" && $2 == 64 {printf "%d", 665000 * $3 / $4 + 90}' "$OUT/throughput.log")
if [ -n "$NEED" ] && [ "$NEED" -lt $((LIMIT - SECONDS - 100)) ]; then
  timeout $((LIMIT - SECONDS - 100)) python3 -W ignore -m calib_cli run stages/default-bbd.toml --run $RUN \
    --var modulus=1.5e8 --var 'heap_options=--repeats 2 --engine gpu' > "$OUT/bbd.log" 2>&1
  echo "bbd rc $? in $((SECONDS - T0)) s (expected ${NEED} s), done at ${SECONDS} s" | tee -a "$OUT/gpu.txt"
else
  echo "bbd skipped: expected ${NEED:-?} s, $((LIMIT - SECONDS - 100)) s left" | tee -a "$OUT/gpu.txt"
fi
cp $RUN/simulate/results.parquet "$OUT/bbd_results.parquet" 2>/dev/null
(cd $RUN && tar czf "$OUT/bbd.tgz" bbd simulate/results.parquet 2>/dev/null)
wait
echo "tests done at ${SECONDS} s" | tee -a "$OUT/gpu.txt"
if [ $((LIMIT - SECONDS)) -gt 90 ]; then
  timeout $((LIMIT - SECONDS - 5)) python3 -W ignore benchmarks/gpu_agree.py --engine gpu --seeds 8 \
    --csv "$OUT/agree_gpu.csv" > "$OUT/agree.log" 2>&1
fi
echo "agreement done at ${SECONDS} s" | tee -a "$OUT/gpu.txt"
tail -5 "$OUT/bbd.log"; cat "$OUT/test_gpu.log" "$OUT/agree.log" 2>/dev/null | tail -20
