#!/bin/bash
# A short second call on a lent GPU machine (the device tool's `run`, carry [".whl"], timeout_s 260), after
# gpu_device.sh: what the engine's defaults are chosen by.
#  1. the contact layout's crossover: one thread a grain (`graph`) against a thread a neighbour slot
#     (`graph+pair`) at 1, 2, 4 and 8 `default` heaps (4k-32k grains), in both precisions: gpu_device.sh
#     found the slot layout 1.5x faster for one heap (4k grains) and 1.1x slower for one `paper` heap (45k),
#     both on fresh fills; since 2026-11-29 the heaps are in contact (benchmarks/heap_states.py), where the
#     crossover (gpu.PAIR_BELOW_GRAINS, 24,000 grains) may lie elsewhere;
#  2. the cohesive case's 8 heaps in double precision on the GPU, beside the mixed ones gpu_device.sh ran
#     on it (same seeds), so that the precision's effect is read apart from the engine's;
#  3. with the time left, where a step's time goes at 64 heaps in both precisions.
# Wheels and the tree as for gpu_device.sh (see its header). Everything goes under $OUT.
LIMIT=${LIMIT:-230}   # seconds for the whole script
source benchmarks/gpu_env.sh
timeout 100 python3 -W ignore benchmarks/gpu_throughput.py --batches 1,2,4,8 --paper-batches "" --steps 1000 \
  --warmup 100 --cpu-heaps 1 --cpu-workers 0 --modes graph,graph+pair,graph/mixed,graph+pair/mixed 2>&1 |
  tee "$OUT/layout.log"
log "layout crossover done (rc $?)"
cp benchmarks/gpu_logs/2026-11-28c/agree.csv "$OUT/agree.csv"
timeout 70 python3 -W ignore benchmarks/gpu_agree.py --engine gpu --precision double --cases cohesive \
  --csv "$OUT/agree.csv" 2>&1 | tee "$OUT/agree.log"
log "double-precision GPU heaps done (rc $?)"
LEFT=$((LIMIT - SECONDS - 5))
if [ $LEFT -gt 30 ]; then
  timeout $LEFT python3 -W ignore benchmarks/gpu_kernel_times.py --batches 64 --precisions double,mixed 2>&1 |
    tee "$OUT/kernel_times64.log"
  log "kernel times at 64 heaps done (rc $?)"
fi
