#!/usr/bin/env bash
# Install and cache what the vcan VM needs (tests/vm/run-vcan-suite.sh boots it).
#
# The kernels of the development and CI machines have no CAN support, so the vcan
# tests run in a small VM: virtme-ng boots a Debian kernel (which carries the vcan
# module) under qemu's software emulation (TCG), with this machine's own filesystem
# as the guest's root. This script, idempotent, installs:
#   1. Debian packages: qemu-system-x86 (the VM), busybox-static (virtme-ng's
#      initramfs), kmod (modprobe, depmod), iproute2 (ip link), file (kernel version),
#      can-utils (canplayer: plays the gateway test's recorded traffic into vcan0 at
#      full rate, which a Python sender under TCG cannot);
#   2. a Debian kernel image, the current dependency of linux-image-amd64, fetched with
#      'apt-get download' and unpacked into the cache (NOT installed into /boot);
#   3. virtme-ng (pinned) in its own venv in the cache.
# Cache: $RAILGW_VM_CACHE, default ${XDG_CACHE_HOME:-$HOME/.cache}/railgw-vm (about
# 450 MB). A second run only checks. RAILGW_VM_KERNEL_REFRESH=1 fetches the newest kernel.
set -euo pipefail

VIRTME_NG_VERSION=1.42
CACHE=${RAILGW_VM_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/railgw-vm}
PY=${PYTHON:-python3}

say() { echo "== vm setup: $*"; }
die() { echo "vm setup: error: $*" >&2; exit 1; }

# The guest sees the host's filesystem, but virtme-ng mounts empty tmpfs over these
# directories, so a cache below them would be invisible inside the VM.
case "$CACHE/" in
  /var/cache/*|/var/tmp/*|/var/log/*|/var/lib/apt/*|/var/lib/private/*)
    die "the cache $CACHE is hidden inside the VM (virtme-ng mounts tmpfs there); set RAILGW_VM_CACHE elsewhere" ;;
esac
mkdir -p "$CACHE"
CACHE=$(cd "$CACHE" && pwd -P)
say "cache $CACHE"

# ---------------------------------------------------------------- 1. Debian packages
as_root() {
  if [ "$(id -u)" = 0 ]; then "$@"; elif command -v sudo >/dev/null; then sudo "$@"; else
    die "need root for: $*"; fi
}
APT_UPDATED=0
apt_update_once() {
  if [ "$APT_UPDATED" = 0 ]; then
    say "apt-get update"
    as_root apt-get update -qq
    APT_UPDATED=1
  fi
}
missing=()
command -v qemu-system-x86_64 >/dev/null || missing+=(qemu-system-x86)
[ -x /bin/busybox ] || [ -x /usr/bin/busybox ] || command -v busybox >/dev/null \
  || missing+=(busybox-static)
command -v modprobe >/dev/null && command -v depmod >/dev/null \
  || [ -x /usr/sbin/depmod ] || [ -x /sbin/depmod ] || missing+=(kmod)
command -v ip >/dev/null || [ -x /usr/sbin/ip ] || [ -x /sbin/ip ] || missing+=(iproute2)
command -v file >/dev/null || missing+=(file)
command -v canplayer >/dev/null || missing+=(can-utils)
if [ ${#missing[@]} -gt 0 ]; then
  command -v apt-get >/dev/null || die "no apt-get: install ${missing[*]} yourself"
  apt_update_once
  say "apt-get install --no-install-recommends ${missing[*]}"
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
    "${missing[@]}" >/dev/null
else
  say "Debian packages present (qemu-system-x86, busybox, kmod, iproute2, file, can-utils)"
fi
DEPMOD=$(command -v depmod || echo /usr/sbin/depmod)

# ---------------------------------------------------------------- 2. the kernel
current_kernel() { [ -f "$CACHE/kernel/current" ] && cat "$CACHE/kernel/current" || true; }
kernel_ok() {  # version -> 0 if its image and vcan module are unpacked
  local k=$1 d="$CACHE/kernel/$1"
  [ -n "$k" ] && [ -f "$d/boot/vmlinuz-$k" ] && {
    [ -f "$d/lib/modules/$k/modules.dep" ] || [ -f "$d/usr/lib/modules/$k/modules.dep" ]; }
}
KVER=$(current_kernel)
if kernel_ok "$KVER" && [ "${RAILGW_VM_KERNEL_REFRESH:-0}" != 1 ]; then
  say "kernel $KVER (cached)"
else
  apt_update_once
  PKG=$(apt-cache depends linux-image-amd64 2>/dev/null \
        | awk '$1 == "Depends:" && $2 ~ /^linux-image-[0-9]/ { print $2; exit }')
  [ -n "$PKG" ] || die "apt-cache depends linux-image-amd64 names no linux-image-<version>"
  KVER=${PKG#linux-image-}
  if kernel_ok "$KVER"; then
    say "kernel $KVER (cached)"
  else
    say "fetching the Debian kernel $PKG (apt-get download; about 70 MB) and unpacking it"
    tmp=$(mktemp -d "$CACHE/.fetch.XXXXXX")
    dl=$(mktemp -d "${TMPDIR:-/tmp}/railgw-kernel.XXXXXX")
    trap 'rm -rf "$tmp" "$dl"' EXIT
    # As root, apt downloads as its sandbox user _apt, which must be able to write here.
    chmod 755 "$dl"; [ "$(id -u)" != 0 ] || chown _apt "$dl" 2>/dev/null || true
    (cd "$dl" && apt-get download -qq "$PKG")
    deb=$(ls "$dl"/*.deb)
    dpkg -x "$deb" "$tmp/root"
    rm -rf "$dl"
    [ -f "$tmp/root/boot/vmlinuz-$KVER" ] || die "$deb has no boot/vmlinuz-$KVER"
    if [ -d "$tmp/root/lib/modules/$KVER" ]; then base="$tmp/root"; else base="$tmp/root/usr"; fi
    [ -f "$base/lib/modules/$KVER/kernel/drivers/net/can/vcan.ko" ] \
      || ls "$base/lib/modules/$KVER/kernel/drivers/net/can/"vcan.ko* >/dev/null 2>&1 \
      || die "$PKG carries no vcan module"
    say "depmod $KVER"
    "$DEPMOD" -b "$base" "$KVER"
    rm -rf "${CACHE:?}/kernel/$KVER"
    mkdir -p "$CACHE/kernel"
    mv "$tmp/root" "$CACHE/kernel/$KVER"
    rm -rf "$tmp"; trap - EXIT
  fi
  echo "$KVER" > "$CACHE/kernel/current"
  # Keep only the kernel in use.
  for d in "$CACHE"/kernel/*/; do
    [ "$(basename "$d")" = "$KVER" ] || { say "removing old kernel $(basename "$d")"; rm -rf "$d"; }
  done
fi

# ---------------------------------------------------------------- 3. virtme-ng
if [ -x "$CACHE/venv/bin/vng" ] \
   && [ "$("$CACHE/venv/bin/vng" --version 2>/dev/null | awk '{print $NF}')" = "$VIRTME_NG_VERSION" ]; then
  say "virtme-ng $VIRTME_NG_VERSION (cached)"
else
  say "pip install virtme-ng==$VIRTME_NG_VERSION into $CACHE/venv"
  rm -rf "$CACHE/venv"
  "$PY" -m venv "$CACHE/venv"
  "$CACHE/venv/bin/python" -m pip install -q --disable-pip-version-check \
    "virtme-ng==$VIRTME_NG_VERSION"
fi
mkdir -p "$CACHE/numba" "$CACHE/results"

say "ready: $(qemu-system-x86_64 --version | head -1); kernel $KVER; virtme-ng $VIRTME_NG_VERSION"
