#!/usr/bin/env bash
# Sets up everything the SDK needs on a fresh machine, idempotently:
#   - a virtual environment in .venv with the core, every plugin in plugins/ (editable,
#     registered through their entry points exactly like third-party plugins) and dev tools,
#     all pinned by constraints.txt (torch pinned to the CPU build);
#   - Xvfb (Debian package) for the display tests and Chromium for the viewer's browser
#     test, when running as root with apt.
# Re-running is cheap: pip runs only when pyproject/constraints changed.
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${PYTHON:-python3}"
shopt -s nullglob

if [ ! -x .venv/bin/python ]; then
  echo "[bootstrap] creating .venv with $($PY --version)"
  "$PY" -m venv .venv
fi

stamp=.venv/.thintact-installed
want=$(cat constraints.txt pyproject.toml plugins/*/pyproject.toml | sha256sum | cut -c1-16)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "[bootstrap] installing the SDK, its plugins and dev tools (pinned by constraints.txt)"
  args=(-e ".[genicam,display,dev,ray,live]")
  for d in plugins/*/; do
    extra=""
    grep -q '^dxf = ' "$d/pyproject.toml" 2>/dev/null && extra="[dxf]"  # thintact_masks: DXF import
    [ -f "$d/pyproject.toml" ] && args+=(-e "${d%/}$extra")
  done
  .venv/bin/python -m pip install --disable-pip-version-check -q -c constraints.txt "${args[@]}"
  echo "$want" > "$stamp"
else
  echo "[bootstrap] .venv up to date"
fi

if ! command -v Xvfb >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "[bootstrap] installing Xvfb for the display tests"
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq xvfb >/dev/null) \
      || echo "[bootstrap] warning: could not install Xvfb; display tests will be skipped"
  else
    echo "[bootstrap] warning: Xvfb missing and not root; display tests will be skipped"
  fi
fi

if ! command -v chromium >/dev/null 2>&1 && ! command -v chromium-browser >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "[bootstrap] installing Chromium for the viewer's browser test"
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
      || echo "[bootstrap] warning: could not install Chromium; the viewer's browser test will be skipped"
  else
    echo "[bootstrap] warning: Chromium missing and not root; the viewer's browser test will be skipped"
  fi
fi
