#!/usr/bin/env bash
# The robot computer's install path, checked end to end: wheels of the SDK and of every plugin
# in plugins/ (pip wheel --no-deps, built from a copy of this working tree), installed with plain
# pip into a fresh virtual environment in a temporary directory (pinned by constraints.txt; pip's
# cache and configuration are used as they are, so the pinned CPU torch comes from wherever pip
# gets it on this host), then, from an empty directory and with no file of the checkout on the
# path, the README's robot example and `thintact demo --out ...`. Any failure ends the script
# with a line saying which step failed and a non-zero status.
#
#   tools/check_pip_install.sh            # PYTHON=python3.12 tools/check_pip_install.sh
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
PY="${PYTHON:-python3}"
work="$(mktemp -d "${TMPDIR:-/tmp}/thintact-pip-check.XXXXXX")"
trap 'rm -rf "$work"' EXIT
start=$(date +%s)
fail() { echo "check_pip_install: FAILED: $*" >&2; exit 1; }
step() { echo "[pip-check] $*"; }

step "copying the working tree (no .venv, .git, build outputs) to $work/src"
mkdir -p "$work/src" "$work/wheels" "$work/run"
tar -C "$repo" --exclude=./.venv --exclude=./.git --exclude='*.egg-info' --exclude=build \
    --exclude=dist --exclude=__pycache__ --exclude=./demo-output -cf - . \
  | tar -C "$work/src" -xf - || fail "copying the working tree"

step "building wheels: the SDK and $(ls -d "$work"/src/plugins/*/ | wc -l) plugins"
plugins=()
for d in "$work"/src/plugins/*/; do
  [ -f "$d/pyproject.toml" ] && plugins+=("$d")
done
"$PY" -m pip wheel --disable-pip-version-check -q --no-deps -w "$work/wheels" \
  "$work/src" "${plugins[@]}" || fail "pip wheel of the SDK and its plugins"
ls "$work"/wheels/*.whl | sed 's#.*/#    #'

step "installing the wheels into a fresh venv ($("$PY" --version))"
"$PY" -m venv "$work/venv" || fail "python -m venv"
"$work/venv/bin/python" -m pip install --disable-pip-version-check -q \
  -c "$repo/constraints.txt" "$work"/wheels/*.whl || fail "pip install of the wheels"

cd "$work/run"
unset THINTACT_CALIBRATION_PATH PYTHONPATH
py="$work/venv/bin/python"
where=$("$py" -c 'import thintact_sdk, thintact_virtual; print(thintact_sdk.__file__)') \
  || fail "import thintact_sdk from the fresh venv"
case "$where" in
  "$work/venv/"*) ;;
  *) fail "thintact_sdk imported from $where, not from the fresh venv" ;;
esac

step "README robot example (from an empty directory)"
example=$("$py" - "$repo/README.md" <<'EOF'
import re, sys
text = open(sys.argv[1], encoding="utf-8").read()
block = re.search(r"## Robot example\s+```python\n(.*?)```", text, re.S)
if block is None:
    sys.exit("README.md has no '## Robot example' python block")
print(block.group(1))
EOF
) || fail "extracting the robot example from README.md"
out=$("$py" -c "$example") || fail "the README robot example exited with an error"
echo "    $out"
[ -n "$out" ] || fail "the README robot example printed nothing (no contact frame)"

step "thintact demo --out $work/run/demo"
"$work/venv/bin/thintact" demo --out "$work/run/demo" || fail "thintact demo"
[ -s "$work/run/demo/demo.png" ] || fail "thintact demo wrote no demo.png"
[ -z "$(ls -A "$work/run" | grep -v '^demo$')" ] || fail "files appeared in the working directory: $(ls -A "$work/run")"

step "passed in $(( $(date +%s) - start )) s"
