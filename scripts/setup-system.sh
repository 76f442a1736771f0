#!/usr/bin/env bash
# Debian packages the project needs: OSMesa for the simulator's CPU rendering, gimp-data for the
# photographic textures of the simulated home, Chromium for the dashboard's browser test.
# HAProxy: the load balancer in front of several server processes (`teachrepeat cluster`).
# PostgreSQL: its server programs (/usr/lib/postgresql/*/bin) run a throw-away server for the
# PostgreSQL tests and benchmarks (server/storage/pgserver.py); the cluster the package may
# start on port 5432 is not used.
# Installs only what is missing; needs root (or sudo) to install.
set -euo pipefail
packages=(libosmesa6 gimp-data chromium haproxy postgresql)
missing=()
for p in "${packages[@]}"; do
  dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
((${#missing[@]} == 0)) && exit 0
sudo=""
if [[ $(id -u) -ne 0 ]]; then
  command -v sudo >/dev/null || { echo "need root to install: ${missing[*]}" >&2; exit 1; }
  sudo="sudo"
fi
echo "installing Debian packages: ${missing[*]}"
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
