#!/usr/bin/env bash
# Device call 2 (2026-11-28): bench targets (target 3 with its CPU baseline in one run),
# tests/test_gpu.py at this commit, bench dataset on both variants; each step time-boxed.
T0=$(date +%s); BUDGET=${BUDGET:-540}
source .devcarry/setup.sh
W=/tmp/w; rm -rf $W; mkdir -p $W
step() { local n=$1 m=$2; shift 2; local l=$(( BUDGET - ($(date +%s) - T0) - 10 )); local t=$(( m < l ? m : l ));
  if [ $t -lt 20 ]; then echo "### SKIP $n ($l s left)"; return; fi
  echo "### STEP $n timeout $t at $(( $(date +%s) - T0 )) s: $*"; local s=$(date +%s.%N)
  timeout -k 5 $t "$@"; local rc=$?; echo "### END $n rc=$rc wall=$(python3 -c "import time;print(round(time.time()-$s,1))") s"; }
{
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader; nproc; git log --oneline -1
$PY -c "import numpy,pandas,cv2,mitsuba,drjit,trimesh;print('numpy',numpy.__version__,'pandas',pandas.__version__,'cv2',cv2.__version__,'mitsuba',mitsuba.__version__,'drjit',drjit.__version__)"
$IMAGEIO_FFMPEG_EXE -version | head -1
step targets 200 $PY -m bench.cli bench targets --out $W/targets
step pytest-gpu 230 $PY -m pytest -q tests/test_gpu.py -p no:cacheprovider --durations=0
step bdata-cuda 60 $PY -m bench.cli bench dataset --quick --frames 30 --variant cuda_ad_rgb --out $W/bdc
step bdata-cpu 60 $PY -m bench.cli bench dataset --quick --frames 30 --variant llvm_ad_rgb --out $W/bdl
echo "### done after $(( $(date +%s) - T0 )) s"
} 2>&1 | tee $OUT/log.txt
grep -c "more than one OptiX shader binding table" $OUT/log.txt
cp $W/targets/targets.csv $W/targets/manifest.json $OUT/ 2>/dev/null
(cd $W && find . -name '*.json' -size -2M | tar czf $OUT/manifests.tar.gz -T -)
