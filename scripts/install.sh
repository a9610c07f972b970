#!/usr/bin/env bash
# One install script for every place the project runs: the README's commands (via make),
# the Debian 13 test root filesystem, and docker/Dockerfile.
#
#   scripts/install.sh system   Debian packages only (apt-get; sudo when not root)
#   scripts/install.sh venv     .venv from /usr/bin/python3 with system site packages,
#                               the package installed editable with its extras
#   scripts/install.sh          both
#
# Quick on the second run: apt is skipped when every package is present, pip when the
# stamp in .venv is newer than pyproject.toml and this script.
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv=${BRAINSHIFT_VENV:-$here/.venv}
extras=${BRAINSHIFT_EXTRAS:-test,viz,lint}

# Debian's own builds: DOLFINx 0.5.2 on Debian 12, 0.9.0 on Debian 13.
APT_PACKAGES=(
  python3-dolfinx-real python3-petsc4py python3-mpi4py python3-gmsh python3-meshio
  python3-h5py python3-scipy python3-matplotlib python3-nibabel python3-skimage python3-pytest
  python3-venv python3-pip python3-dev
  openmpi-bin make git ca-certificates
  # Optimised BLAS for MUMPS's dense fronts: with Debian's reference BLAS the Cholesky factor
  # of the 5 mm brain took 10.3 s, with this 1.9 s (serial build: no threads to fight MPI ranks).
  libopenblas0-serial
  # Progress bars, and off-screen pictures: VTK (pyvista, from PyPI) opens OpenGL at run time
  # through EGL with Mesa's software renderer, or OSMesa, no display needed.
  python3-tqdm libgl1 libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6 libx11-6 libxrender1 libxcursor1
)

say() { printf '[install] %s\n' "$*"; }

as_root() {
  if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi
}

install_system() {
  local missing=()
  for p in "${APT_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [ ${#missing[@]} -eq 0 ]; then
    say "Debian packages present"
    return
  fi
  say "apt-get install ${missing[*]}"
  as_root env DEBIAN_FRONTEND=noninteractive apt-get update -q
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}"
}

install_venv() {
  local stamp=$venv/.brainshift-installed
  if [ -f "$stamp" ] && [ "$stamp" -nt "$here/pyproject.toml" ] && [ "$stamp" -nt "$0" ] \
     && [ "$(cat "$stamp")" = "$extras" ]; then
    say "virtual environment up to date ($venv)"
    return
  fi
  # Debian's python3 sees dolfinx/petsc4py; a python3 elsewhere on PATH may not.
  if [ ! -x "$venv/bin/python" ]; then
    say "creating $venv"
    /usr/bin/python3 -m venv --system-site-packages "$venv"
  fi
  # A newer numpy from PyPI breaks Debian's petsc4py ('numpy.dtype size changed'): pin it.
  local constraints=$venv/constraints.txt
  "$venv/bin/python" -c 'import numpy; print(f"numpy=={numpy.__version__}")' > "$constraints"
  say "pip install -e .[$extras] (constraints: $(cat "$constraints"))"
  "$venv/bin/python" -m pip install -q --disable-pip-version-check -c "$constraints" \
    -e "$here[$extras]"
  printf '%s' "$extras" > "$stamp"
}

case "${1:-all}" in
  system) install_system ;;
  venv) install_venv ;;
  all) install_system; install_venv ;;
  *) echo "usage: $0 [system|venv|all]" >&2; exit 2 ;;
esac
