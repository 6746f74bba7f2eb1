#!/usr/bin/env bash
# Prepare the GPU backend's device check (docs/gpu.md, "The device check") on this machine, before a machine with a
# GPU runs tools/device_check.sh over a copy of this repository.
#
#   bash tools/prepare_device_check.sh [YARDSTICK_DIR] [--wheels]
#
# * copies the GPU yardstick (cuda_mls.py and its common.py, a hand-written program that is not part of mpmref) from
#   YARDSTICK_DIR (default ../shared/peers) into .gpu/, a folder git ignores, to travel with the repository;
# * with --wheels, downloads into .whl/ (ignored too) the wheel of numba-cuda for a Python 3.12 x86-64 machine,
#   for a GPU machine whose image lacks it (the image this was written for has numba-cuda, NumPy, SciPy, Numba,
#   tqdm and matplotlib, everything the check imports: nothing needs to travel there).
set -euo pipefail
cd "$(git rev-parse --show-toplevel)"
source_dir="../shared/peers"
wheels=0
for arg in "$@"; do
    case "$arg" in
        --wheels) wheels=1 ;;
        *) source_dir="$arg" ;;
    esac
done
exclude="$(git rev-parse --git-path info/exclude)"
for folder in /.gpu/ /.whl/; do
    grep -qxF "$folder" "$exclude" 2>/dev/null || echo "$folder" >> "$exclude"
done
mkdir -p .gpu
cp "$source_dir/cuda_mls.py" "$source_dir/common.py" .gpu/
echo "yardstick copied to .gpu/ ($(ls .gpu | tr '\n' ' '))"
if [ "$wheels" = 1 ]; then
    mkdir -p .whl
    python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
        --platform manylinux2014_x86_64 -d .whl numba-cuda==0.30.4
    ls -la .whl
fi
