#!/usr/bin/env bash
# Download, here, the wheels the GPU machine's image lacks for the SDK (issue 11's GPU checks).
#
# The lent GPU machines (docs: the device tool's KINDS.md) run Python 3.12 with torch, numpy,
# scipy, OpenCV, matplotlib, rich, pluggy, PyYAML, pytest, pytest-timeout and hypothesis, and
# reach no registry. What the SDK imports beyond that is fetched here as wheels for CPython
# 3.12 / manylinux x86-64 into .whl/ (git ignores it), at the versions constraints.txt pins;
# the device run carries .whl (`carry: [".whl"]`) and tools/device_check.sh installs them.
#
# Usage (repository root):  bash tools/device_wheels.sh
set -euo pipefail
cd "$(dirname "$0")/.."
pin() {  # the version constraints.txt pins for a distribution name (- and _ alike)
  local name="${1//_/-}"
  grep -iE "^${name//-/[-_]}==" constraints.txt | head -n 1
}
wanted=(pydantic pydantic_core annotated-types typing-inspection pyserial pyusb mcap mcap-ros2-support lz4 zstandard)
specs=()
for w in "${wanted[@]}"; do
  spec=$(pin "$w")
  [ -n "$spec" ] || { echo "device_wheels: $w is not pinned in constraints.txt" >&2; exit 2; }
  specs+=("$spec")
done
mkdir -p .whl
platforms=()
for n in 2_17 2_27 2_28 2_31 2_34 2_35 2_39; do platforms+=(--platform "manylinux_${n}_x86_64"); done
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  "${platforms[@]}" --platform manylinux2014_x86_64 --platform manylinux1_x86_64 --platform any \
  -d .whl "${specs[@]}"
ls .whl
du -sh .whl
