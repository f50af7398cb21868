#!/usr/bin/env bash
# Idempotent set-up: system libraries open3d needs, then a virtual environment with mfmap and its
# dev tools. A second run checks and skips what is already done.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=${MFMAP_VENV:-.venv}
PY=${PYTHON:-python3}

# open3d's wheel links libusb-1.0 and GL/EGL; libgomp for its OpenMP kernels.
need_apt=()
for lib in libusb-1.0.so.0:libusb-1.0-0 libGL.so.1:libgl1 libEGL.so.1:libegl1 libgomp.so.1:libgomp1; do
    so=${lib%%:*}; pkg=${lib##*:}
    ldconfig -p 2>/dev/null | grep -q "$so" || need_apt+=("$pkg")
done
# The report's 3D view is tested in a real browser: Debian's Chromium, driven by playwright's
# Python package (which then downloads no browser of its own).
[ -x /usr/bin/chromium ] || need_apt+=(chromium)
if [ ${#need_apt[@]} -gt 0 ]; then
    echo "setup: installing system packages: ${need_apt[*]}"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${need_apt[@]}" >/dev/null
fi

if [ ! -x "$VENV/bin/python" ]; then
    echo "setup: creating virtual environment $VENV"
    "$PY" -m venv "$VENV"
fi

stamp="$VENV/.mfmap-setup"
want=$(cat pyproject.toml scripts/setup.sh | sha256sum | cut -d' ' -f1)
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && "$VENV/bin/python" -c "import mfmap, open3d, gtsam" 2>/dev/null; then
    exit 0
fi
echo "setup: installing mfmap and its dependencies into $VENV"
"$VENV/bin/python" -m pip install -q --upgrade "pip>=25.1"
"$VENV/bin/python" -m pip install -q -e ".[ray]" --group dev
# Peers used by the benchmarks and cross-checks (not runtime dependencies of mfmap).
"$VENV/bin/python" -m pip install -q -r requirements-peers.txt
echo "$want" > "$stamp"
