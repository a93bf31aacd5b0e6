#!/usr/bin/env bash
# Make sure a Vulkan loader and at least one Vulkan driver (ICD) are installed.
#
# If any ICD is already registered, this does nothing. Otherwise, on Debian 12 (bookworm) as root,
# it installs the Vulkan loader and Mesa's software rasteriser lavapipe (`mesa-vulkan-drivers`),
# preferring bookworm-backports' Mesa 25 (3-7x faster compute than bookworm's Mesa 22.3, see
# docs/lavapipe.md). Anywhere else it fails with a message saying what to install by hand.
set -euo pipefail

have_icd() {
    local d
    for d in /usr/share/vulkan/icd.d /etc/vulkan/icd.d /usr/local/share/vulkan/icd.d; do
        if compgen -G "$d/*.json" >/dev/null; then return 0; fi
    done
    [ -n "${VK_ICD_FILENAMES:-}${VK_DRIVER_FILES:-}" ]
}
# The cache is read whole before it is searched: under pipefail, `ldconfig -p | grep -q` fails
# whenever grep exits at its match before ldconfig has written everything (SIGPIPE), which made
# this script reinstall (and once fail) on a machine with the loader in place.
have_loader() {
    local cache
    cache="$(ldconfig -p 2>/dev/null)" || return 1
    grep -q 'libvulkan\.so\.1' <<<"$cache"
}

if have_loader && have_icd; then
    exit 0
fi

echo "ensure-vulkan: no Vulkan driver found; installing the Vulkan loader and lavapipe (software Vulkan)." >&2
if [ "$(id -u)" -ne 0 ]; then
    echo "ensure-vulkan: error: installing packages needs root. Run as root, or install a Vulkan driver" >&2
    echo "  yourself (Debian/Ubuntu: 'sudo apt-get install libvulkan1 mesa-vulkan-drivers')." >&2
    exit 1
fi
if ! command -v apt-get >/dev/null 2>&1 || [ ! -r /etc/os-release ]; then
    echo "ensure-vulkan: error: this is not a Debian-like system; install a Vulkan driver by hand" >&2
    echo "  (the Vulkan loader and, without a GPU, Mesa's lavapipe)." >&2
    exit 1
fi
# shellcheck disable=SC1091
. /etc/os-release
export DEBIAN_FRONTEND=noninteractive
if [ "${VERSION_CODENAME:-}" = "bookworm" ]; then
    list=/etc/apt/sources.list.d/mipnerf-bookworm-backports.list
    if ! grep -rqs 'bookworm-backports' /etc/apt/sources.list /etc/apt/sources.list.d/; then
        echo "ensure-vulkan: adding bookworm-backports (for Mesa 25) in $list" >&2
        echo "deb http://deb.debian.org/debian bookworm-backports main" >"$list"
    fi
    apt-get update -qq
    apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1 >/dev/null
else
    apt-get update -qq
    apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
fi
if have_loader && have_icd; then
    echo "ensure-vulkan: installed: $(dpkg-query -W -f='${Package} ${Version}' mesa-vulkan-drivers)" >&2
else
    echo "ensure-vulkan: error: the install finished but no Vulkan driver is registered" >&2
    exit 1
fi
