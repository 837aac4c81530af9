#!/usr/bin/env bash
# Installs what scapo needs on a fresh machine; safe to run again (it skips what is present).
#  1. Vulkan for SAPIEN: on Debian bookworm without a usable device, Mesa >= 24.3 (lavapipe)
#     from bookworm-backports (SPEC section 12). Other systems: prints what to install.
#  2. A virtual environment in .venv (override with SCAPO_VENV), torch 2.13.0 (CPU build) when no
#     torch is importable, then this package in editable mode with its dev, ray, maniskill, viewer and
#     tensorboard extras, at the versions of constraints.txt.
#  3. Chromium (Debian package, about 100 MB) for the browser test of the viewer, where apt can install it.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${SCAPO_VENV:-$here/.venv}"
py="${PYTHON:-python3}"
log() { printf '[setup] %s\n' "$*" >&2; }

mesa_ok() {
  # lavapipe from Mesa >= 24.3, or any vendor Vulkan ICD (GPU machines)
  local v
  v="$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)"
  if [ -n "$v" ] && dpkg --compare-versions "$v" ge 24.3; then return 0; fi
  ls /usr/share/vulkan/icd.d/nvidia_icd.json /etc/vulkan/icd.d/nvidia_icd.json >/dev/null 2>&1 && return 0
  return 1
}

install_vulkan() {
  if mesa_ok; then log "Vulkan driver present"; return 0; fi
  if [ ! -r /etc/os-release ] || ! grep -q 'VERSION_CODENAME=bookworm' /etc/os-release; then
    log "WARNING: no Mesa >= 24.3 Vulkan driver found and this is not Debian bookworm;"
    log "         install Mesa >= 24.3 (mesa-vulkan-drivers, libvulkan1) or a GPU Vulkan driver yourself."
    return 0
  fi
  local sudo=""
  if [ "$(id -u)" != 0 ]; then
    if command -v sudo >/dev/null; then sudo="sudo"; else
      log "ERROR: need root to install mesa-vulkan-drivers from bookworm-backports"; return 1; fi
  fi
  if ! grep -rqs 'bookworm-backports' /etc/apt/sources.list /etc/apt/sources.list.d/; then
    local mirror
    # the mirror of the existing bookworm entry (deb822 "URIs:" lines, or one-line "deb" entries)
    mirror="$( { grep -hs '^URIs:' /etc/apt/sources.list.d/*.sources | awk '{print $2}';
                 grep -hs '^deb ' /etc/apt/sources.list | awk '{print $2}'; } | grep -m1 -E '/debian/?$' || true)"
    mirror="${mirror:-http://deb.debian.org/debian}"
    log "adding bookworm-backports ($mirror) to apt sources"
    printf 'Types: deb\nURIs: %s\nSuites: bookworm-backports\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' \
      "$mirror" | $sudo tee /etc/apt/sources.list.d/bookworm-backports.sources >/dev/null
  fi
  log "installing mesa-vulkan-drivers libvulkan1 from bookworm-backports"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1 >/dev/null
}

install_python() {
  if [ ! -x "$venv/bin/python" ]; then
    log "creating virtual environment $venv"
    "$py" -m venv "$venv"
  fi
  local vpy="$venv/bin/python"
  local stamp="$venv/.scapo-installed"
  local want
  want="$(cat "$here/pyproject.toml" "$here/setup.py" "$here/constraints.txt" | sha256sum | cut -c1-16)"
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && "$vpy" -c "import scapo, sapien, torch" 2>/dev/null; then
    log "python environment up to date"
    return 0
  fi
  if ! "$vpy" -c "import torch" >/dev/null 2>&1; then
    log "installing torch==2.13.0 (CPU build) and numpy"
    "$vpy" -m pip install -q --disable-pip-version-check -c "$here/constraints.txt" torch==2.13.0 numpy 2>&1 \
      | grep -v '^WARNING: Location' || true
    "$vpy" -c "import torch" || { log "ERROR: torch install failed"; return 1; }
  fi
  log "installing scapo (editable) with dev, ray, maniskill, viewer and tensorboard extras, at the tested versions (constraints.txt)"
  "$vpy" -m pip install -q --disable-pip-version-check -c "$here/constraints.txt" \
    -e "$here[dev,ray,maniskill,viewer,tensorboard]" \
    2>&1 | grep -v '^WARNING: Location' || true
  "$vpy" -c "import scapo, sapien, torch, ray" || { log "ERROR: package install failed"; return 1; }
  echo "$want" > "$stamp"
}

install_chromium() {
  if command -v chromium >/dev/null || command -v chromium-browser >/dev/null; then log "Chromium present"; return 0; fi
  if ! command -v apt-get >/dev/null; then log "no Chromium and no apt: the browser test of the viewer is skipped"; return 0; fi
  local sudo=""
  if [ "$(id -u)" != 0 ]; then
    if command -v sudo >/dev/null; then sudo="sudo"; else log "no root: the browser test of the viewer is skipped"; return 0; fi
  fi
  log "installing chromium (for the viewer's browser test)"
  $sudo apt-get update -qq >/dev/null 2>&1 || true
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq chromium >/dev/null 2>&1 \
    || log "WARNING: chromium could not be installed; the browser test of the viewer is skipped"
}

install_vulkan
install_python
install_chromium
