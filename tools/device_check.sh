#!/usr/bin/env bash
# The GPU backend's device check, run on a machine with an NVIDIA GPU over a copy of this repository
# (docs/gpu.md, "The device check"): every check that needs the GPU, as JSON lines, within about five minutes.
#
#   bash tools/device_check.sh [options of python -m mpmref.bench.device_check]
#
# Uses the machine's python3 and its packages (NumPy, Numba, numba-cuda, SciPy, tqdm, matplotlib), mpmref from this
# folder (no install), wheels in .whl/ if any (tools/prepare_device_check.sh --wheels), the yardstick in .gpu/ if
# there. Writes device_check.jsonl and the log to $OUT (or reports/device_check).
set -uo pipefail
cd "$(dirname "$0")/.."
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 NUMBA_CACHE_DIR=/tmp/mpmref_numba_cache
if compgen -G ".whl/*.whl" > /dev/null; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
        && export PYTHONPATH="/tmp/site:$PYTHONPATH" || exit 1
fi
out="${OUT:-reports/device_check}"
mkdir -p "$out"
yardstick=()
[ -f .gpu/cuda_mls.py ] && yardstick=(--yardstick .gpu/cuda_mls.py)
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>&1 | head -1
python3 -m mpmref.bench.device_check --out "$out" "${yardstick[@]}" "$@" 2>&1 | tee "$out/device_check.log"
