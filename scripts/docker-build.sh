#!/usr/bin/env bash
# Build docker/Dockerfile (the tests and a demo run as build steps).
#
#   scripts/docker-build.sh [IMAGE_TAG]
#
# Uses a Docker engine when one answers; otherwise podman with --isolation chroot, whose
# debian:trixie base image is imported, when missing, from the Debian 13 root filesystem
# that scripts/debian13.sh builds (no registry or engine needed).
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
tag=${1:-fenics-brainshift}
rootfs=${BRAINSHIFT_ROOTFS:-/var/cache/fenics-brainshift/trixie}
say() { printf '[docker-build] %s\n' "$*"; }

# Trust the host's extra certificate authorities inside the build (removed afterwards).
shopt -s nullglob
added=()
for crt in /usr/local/share/ca-certificates/*.crt; do
  cp "$crt" "$here/docker/ca/" && added+=("$here/docker/ca/$(basename "$crt")")
done
trap 'rm -f "${added[@]}"' EXIT

if command -v docker >/dev/null && docker info >/dev/null 2>&1; then
  say "docker build -t $tag"
  docker build -f "$here/docker/Dockerfile" -t "$tag" "$here"
  exit 0
fi

command -v podman >/dev/null || {
  [ "$(id -u)" -eq 0 ] || { echo "[docker-build] needs docker, or root to install podman" >&2; exit 1; }
  DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends podman fuse-overlayfs
}
if ! podman image exists docker.io/library/debian:trixie; then
  "$here/scripts/debian13.sh" true   # builds (or reuses) the root filesystem, then unmounts
  say "importing $rootfs as docker.io/library/debian:trixie"
  tar -C "$rootfs" --exclude=./work --exclude=./proc/* --exclude=./sys/* --exclude=./dev/* -cf - . \
    | podman import - docker.io/library/debian:trixie
fi
say "podman build --isolation chroot -t $tag"
podman build --isolation chroot -f "$here/docker/Dockerfile" -t "$tag" "$here"
