#!/usr/bin/env bash
# Device call of 2026-11-27: test_gpu.py in one go with the fix on main, and the figures the
# 2026-11-26 calls had no time for (bench dataset's full-frame half, bench detectability, and
# many workers sharing one GPU on longer samples), each CUDA figure with its CPU baseline.
export T0=$(date +%s)
set -o pipefail
{
  source .devcarry/device_setup.sh
  source <(sed -n '/^left()/,/^}/p' bench/benchmarks/gpu_run.sh | sed -n '/^left()/p;/^step()/,/^}/p')
  BUDGET=${BUDGET:-480}
  WORK=$(mktemp -d /tmp/gpu-run4.XXXX); STEPS=$WORK/steps.tsv; : > $STEPS; export PYTHONUNBUFFERED=1
  nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader; nproc
  git log --oneline -1 2>/dev/null
  step pytest-gpu 240 $PY -m pytest -q tests/test_gpu.py -p no:cacheprovider -rA --durations=0
  step bench-dataset-cuda 70 $PY -m bench.cli bench dataset --quick --frames 30 --variant cuda_ad_rgb --out $WORK/bench-dataset-cuda_ad_rgb
  step bench-dataset-cpu 70 $PY -m bench.cli bench dataset --quick --frames 30 --variant llvm_ad_rgb --out $WORK/bench-dataset-llvm_ad_rgb
  IND=(--protocol indoor --foliage soft,dense --distance far,intermediate --branches none,0,50,0+100 --frames-step 4)
  step dataset-16-cuda-w16 100 $PY -m bench.cli dataset "${IND[@]}" --variant cuda_ad_rgb --workers 16 --out $WORK/dataset-16-cuda_ad_rgb-w16
  step dataset-16-cpu-w16 100 $PY -m bench.cli dataset "${IND[@]}" --variant llvm_ad_rgb --workers 16 --out $WORK/dataset-16-llvm_ad_rgb-w16
  step study-bench-cuda 60 $PY -m bench.cli bench detectability --quick --variant cuda_ad_rgb
  step study-bench-cpu 60 $PY -m bench.cli bench detectability --quick --variant llvm_ad_rgb
  (cd $WORK && find . \( -name manifest.json -o -name bench.json -o -name steps.tsv -o -name '*.csv' \) -size -2M | tar czf $OUT/run4.tar.gz -T -)
  echo "### run4 done after $(( $(date +%s) - T0 )) s"
} 2>&1 | tee "$OUT/log.txt"
awk '/^### STEP/{s=$3} /more than one OptiX shader binding table/{c[s]++} END{for (k in c) print "OptiX SBT warnings in step", k ":", c[k]}' "$OUT/log.txt"
