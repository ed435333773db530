#!/usr/bin/env bash
# One-time (idempotent) setup of a fresh Debian machine with Python 3.11: the Debian
# packages contactflow needs, then a virtual environment in .venv with the project installed.
set -euo pipefail
cd "$(dirname "$0")/.."

log() { printf '\033[1;34m[setup]\033[0m %s\n' "$*"; }

need_debs=()
missing() { ! dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "install ok installed"; }
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  # libusb: open3d; iproute2: multi-host tests in network namespaces; openssl: test certificates.
  for p in libusb-1.0-0 iproute2 openssl; do missing "$p" && need_debs+=("$p"); done
  codename=$(. /etc/os-release && echo "${VERSION_CODENAME:-}")
  mesa_ok=0
  if dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null | grep -qE '^(2[4-9]|[3-9][0-9])\.'; then mesa_ok=1; fi
  if [ ${#need_debs[@]} -gt 0 ] || { [ "$codename" = bookworm ] && [ $mesa_ok = 0 ]; }; then
    if [ "$codename" = bookworm ] && [ $mesa_ok = 0 ]; then
      # SAPIEN refuses bookworm's Mesa 22 lavapipe; Mesa 25 from backports renders on the CPU.
      cat > /etc/apt/sources.list.d/contactflow-backports.sources <<'SRC'
Types: deb
URIs: http://deb.debian.org/debian
Suites: bookworm-backports
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
SRC
    fi
    log "apt-get update"
    apt-get update -qq
    if [ ${#need_debs[@]} -gt 0 ]; then
      log "installing ${need_debs[*]}"
      DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need_debs[@]}" >/dev/null
    fi
    if [ "$codename" = bookworm ] && [ $mesa_ok = 0 ]; then
      log "installing Mesa Vulkan drivers from bookworm-backports (camera rendering on the CPU)"
      DEBIAN_FRONTEND=noninteractive apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1 >/dev/null \
        || log "Mesa from backports unavailable: cameras fall back to ray casting"
    fi
  fi
else
  log "not root or no apt-get: assuming libusb-1.0-0 and iproute2 are present"
fi

PY=${PYTHON:-}
if [ -z "$PY" ]; then
  for c in python3.11 python3; do
    if command -v "$c" >/dev/null && "$c" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then PY=$c; break; fi
  done
fi
[ -n "$PY" ] || { echo "contactflow needs Python 3.11 (set PYTHON=/path/to/python3.11)" >&2; exit 1; }

if [ ! -x .venv/bin/python ]; then
  log "creating .venv with $PY"
  "$PY" -m venv .venv || { apt-get install -y -qq python3.11-venv >/dev/null && "$PY" -m venv .venv; }
fi
stamp=.venv/.contactflow-installed
want=$(cat pyproject.toml setup.py | sha256sum | cut -c1-16)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  log "installing contactflow and its Python dependencies into .venv"
  .venv/bin/python -m pip install -q --upgrade pip > .venv/pip-install.log 2>&1 || true
  if ! .venv/bin/python -m pip install -q -e ".[test]" >> .venv/pip-install.log 2>&1; then
    tail -30 .venv/pip-install.log >&2
    exit 1
  fi
  .venv/bin/python -c "import contactflow.nodes, zenoh, sapien, pinocchio, ompl, open3d" 2>/dev/null \
    || { echo "[setup] the Python dependencies did not install" >&2; exit 1; }
  echo "$want" > "$stamp"
fi
log "ready: .venv/bin/contactflow"
