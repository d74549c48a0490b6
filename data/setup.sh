#!/usr/bin/env bash
# setup.sh - install the Debian 12 packages hlod needs to build, test and run.
#
# Idempotent: when every package is already installed (dpkg-query) it does
# nothing and needs no network; otherwise it runs apt-get update once and
# apt-get install -y.  Runs unattended (CI=true, no stdin).  Needs root, or
# sudo when it is available.
set -euo pipefail

PACKAGES=(
    build-essential cmake pkg-config
    libassimp-dev libopenimageio-dev libmetis-dev
    libosmesa6-dev libegl-dev libegl-mesa0 libglfw3-dev libmeshoptimizer-dev libturbojpeg0-dev
    libstb-dev libsquish-dev libzstd-dev
    gnuplot-nox libxxhash-dev libfast-float-dev
    clang libclang-rt-14-dev
    xvfb xauth
    strace util-linux procps
    libcurl4-openssl-dev nginx-light iproute2 python3 openssl libmicrohttpd-dev
    libcjson-dev
    parallel munge slurmctld slurmd slurm-client openssh-server openssh-client
    nodejs chromium chromium-driver
)
# npm: Debian's package, unless the installed nodejs brings its own (the
# NodeSource build does, and conflicts with Debian's npm).  tests/run.sh
# runs npm ci; the tiles test (tests/test_tiles.sh) needs node >= 18,
# Debian 12's own (its npm pins allow it: playwright-core 1.61).
command -v npm >/dev/null 2>&1 || PACKAGES+=(npm)

missing=()
for p in "${PACKAGES[@]}"; do
    status=$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null || true)
    [ "$status" = "install ok installed" ] || missing+=("$p")
done

if [ ${#missing[@]} -eq 0 ]; then
    echo "setup: all ${#PACKAGES[@]} packages already installed"
    exit 0
fi

echo "setup: installing ${missing[*]}"
SUDO=()
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then
        SUDO=(sudo -n)
    else
        echo "setup: error: packages missing (${missing[*]}) and not running as root; run as root" >&2
        exit 1
    fi
fi

export DEBIAN_FRONTEND=noninteractive
"${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update </dev/null
"${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y "${PACKAGES[@]}" </dev/null
echo "setup: done"
