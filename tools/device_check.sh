#!/usr/bin/env bash
# Issue 11's GPU checks in one run on a lent GPU machine (the device tool), from a bare image.
#
# Here first:  bash tools/device_wheels.sh          (the wheels the image lacks, into .whl/)
# Then, through the device tool, from the repository root:
#   run(command="bash tools/device_check.sh", carry=[".whl"], timeout_s=540)
# What comes back under $OUT: check.log (everything printed), gpu_tests.log, doctor.txt,
# bench_reconstruct.json (every backend real there, CUDA included, with its PSNR cost and
# the backend the selection chose) and stream.json (raw Bayer -> tactile frames streamed on
# the paper device at 30 fps, 1 and 2 decode workers) and ga_fitness.json (one GA fitness batch
# at the paper's size on the GPU against the numpy path on the CPU, in the same run).
# Each step has its own time limit (LIMIT_SCALE multiplies them), so a slow step costs its
# figure, not the others'.
#
# The SDK and its plugins are installed without dependencies into /tmp/site next to the
# image's own torch (the image's torch version differs from constraints.txt's CPU pin; the
# SDK needs no particular one). PY overrides the interpreter (default python3) and OUT the
# output folder, so the non-GPU steps can be tried on any machine.
set -uo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-python3}
OUT=${OUT:-$(mktemp -d)}
SITE=${SITE:-/tmp/site}
export PYTHONUNBUFFERED=1 MPLBACKEND=Agg THINTACT_CACHE_DIR="$SITE/.cache"
exec > >(tee "$OUT/check.log") 2>&1
t0=$(date +%s)
LIMIT_SCALE=${LIMIT_SCALE:-1}
limit() { local s=$1; shift; timeout --kill-after=10 "$(( s * LIMIT_SCALE ))" "$@"; }
step() { printf '\n== %s (t+%ss)\n' "$1" "$(( $(date +%s) - t0 ))"; }

step "machine"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"
"$PY" -c 'import sys, torch; print(sys.version.split()[0], "torch", torch.__version__, "cuda", torch.cuda.is_available(), torch.cuda.get_device_name(0) if torch.cuda.is_available() else "")'

step "install the SDK and its plugins into $SITE (no index, no dependencies)"
mkdir -p "$SITE"
if compgen -G ".whl/*.whl" >/dev/null; then
  "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" .whl/*.whl || exit 1
fi
"$PY" -m pip install -q --no-index --no-deps --no-build-isolation --no-compile --no-cache-dir --upgrade \
  --target "$SITE" . plugins/thintact_* || exit 1
export PYTHONPATH="$SITE${PYTHONPATH:+:$PYTHONPATH}"
"$PY" -m thintact_sdk.apps.cli.main plugins | head -n 20

step "GPU tests (tests/reconstruction/test_rec_gpu.py: decoders on CUDA agree with numpy, CUDA is measured)"
limit 90 "$PY" -m pytest -q -p no:cacheprovider --rootdir . tests/reconstruction/test_rec_gpu.py tests/reconstruction/test_rec_accelerator_path.py 2>&1 | tee "$OUT/gpu_tests.log"

step "thintact doctor (host, GPU, the backend the selection chooses for thintact-paper)"
limit 45 "$PY" -m thintact_sdk.apps.cli.main doctor --profile thintact-paper 2>&1 | tee "$OUT/doctor.txt"

step "thintact bench reconstruct (paper size, every backend real here)"
limit 150 "$PY" -m thintact_sdk.apps.cli.main bench reconstruct --json --no-mask-compare --iterative-probe 1 --repeats 30 \
  > "$OUT/bench_reconstruct.json" || echo "bench reconstruct failed"
"$PY" - "$OUT/bench_reconstruct.json" <<'EOF'
import json, sys
try:
    d = json.load(open(sys.argv[1]))
except (OSError, ValueError) as err:
    sys.exit(f"no bench result: {err}")
for k, v in d["latency_ms"].items():
    print(f"{v:9.3f} ms  {k}")
print(json.dumps(d.get("backend_choice"), indent=1)[:3000])
EOF

step "streamed tactile frames (paper device, camera 30 fps; 1 and 2 decode workers)"
limit 75 "$PY" tools/bench_stream_workers.py --decoder t2s-closed-form --workers 1 2 --frames 90 > "$OUT/stream.json" \
  || echo "stream bench failed"
cat "$OUT/stream.json"
step "GA fitness batch (paper size, K = 770, 64 genes): torch on the GPU against numpy on the CPU"
limit 75 "$PY" tools/bench_ga_fitness_device.py --device cuda --population 64 --cpu-genes 4 > "$OUT/ga_fitness.json" \
  || echo "GA fitness bench failed"
cat "$OUT/ga_fitness.json"
step "done"
