#!/usr/bin/env bash
# Run a command from this checkout inside a Debian 13 (trixie, DOLFINx 0.9) root filesystem,
# made with debootstrap and provisioned by scripts/install.sh — the same script the README
# and docker/Dockerfile use. No Docker engine needed.
#
#   scripts/debian13.sh                 build (or reuse) the root filesystem, run `make test`
#   scripts/debian13.sh CMD ...         run CMD in the copy of the checkout inside it
#
# The root filesystem is cached outside the checkout (BRAINSHIFT_ROOTFS, default
# /var/cache/fenics-brainshift/trixie) and rebuilt when scripts/install.sh changes.
# Needs root (debootstrap, chroot, mount).
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
rootfs=${BRAINSHIFT_ROOTFS:-/var/cache/fenics-brainshift/trixie}
mirror=${BRAINSHIFT_MIRROR:-http://deb.debian.org/debian}
say() { printf '[debian13] %s\n' "$*"; }

if [ "$(id -u)" -ne 0 ]; then
  exec sudo --preserve-env=BRAINSHIFT_ROOTFS,BRAINSHIFT_MIRROR "$0" "$@"
fi
command -v debootstrap >/dev/null || {
  # a fresh host has no package lists yet: update first, or the install finds nothing
  DEBIAN_FRONTEND=noninteractive apt-get update -q
  DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends debootstrap
}

mounted=()
cleanup() {
  local i
  for ((i=${#mounted[@]}-1; i>=0; i--)); do umount -l "${mounted[$i]}" 2>/dev/null || true; done
}
trap cleanup EXIT

mount_all() {
  mount -t proc proc "$rootfs/proc"; mounted+=("$rootfs/proc")
  mount --rbind /sys "$rootfs/sys"; mount --make-rslave "$rootfs/sys"; mounted+=("$rootfs/sys")
  mount --rbind /dev "$rootfs/dev"; mount --make-rslave "$rootfs/dev"; mounted+=("$rootfs/dev")
  cp -L /etc/resolv.conf "$rootfs/etc/resolv.conf"
}

trust_host_certs() {
  # Trust what the host trusts (a site CA for an egress proxy, say), as a build on this
  # host would; pip in the root filesystem verifies PyPI's certificate against it.
  if compgen -G "/usr/local/share/ca-certificates/*.crt" >/dev/null; then
    mkdir -p "$rootfs/usr/local/share/ca-certificates"
    cp /usr/local/share/ca-certificates/*.crt "$rootfs/usr/local/share/ca-certificates/"
    [ -x "$rootfs/usr/sbin/update-ca-certificates" ] && in_root update-ca-certificates >/dev/null 2>&1 || true
  fi
}

in_root() {
  chroot "$rootfs" /usr/bin/env -i HOME=/root PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    LANG=C.UTF-8 OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 "$@"
}

key=$(sha256sum "$here/scripts/install.sh" | cut -c1-16)
if [ ! -f "$rootfs/.brainshift-$key" ]; then
  say "building $rootfs (install.sh $key)"
  if grep -q " $rootfs/" /proc/mounts; then
    echo "[debian13] something is still mounted under $rootfs; unmount it first" >&2; exit 1
  fi
  rm -rf --one-file-system "$rootfs"
  mkdir -p "$rootfs"
  debootstrap --variant=minbase trixie "$rootfs" "$mirror" > "$rootfs.debootstrap.log" 2>&1 || {
    tail -20 "$rootfs.debootstrap.log"; exit 1; }
  mount_all
  mkdir -p "$rootfs/opt/install"
  cp "$here/scripts/install.sh" "$rootfs/opt/install/install.sh"
  in_root bash /opt/install/install.sh system > "$rootfs.install.log" 2>&1 || {
    tail -30 "$rootfs.install.log"; exit 1; }
  touch "$rootfs/.brainshift-$key"
else
  say "reusing $rootfs (install.sh $key)"
  mount_all
fi
trust_host_certs

# A fresh copy of the tracked files (plus uncommitted edits), never the host's .venv.
src=$rootfs/work/fenics-brainshift
mkdir -p "$src"
find "$src" -mindepth 1 -maxdepth 1 ! -name .venv -exec rm -rf --one-file-system {} +
( cd "$here" && git ls-files -z --cached --others --exclude-standard ) \
  | ( cd "$here" && tar --null -T - -cf - ) | tar -C "$src" -xf -
if [ $# -eq 0 ]; then set -- make test; fi
say "running: $*"
in_root bash -c 'cd /work/fenics-brainshift && "$@"' _ "$@"
