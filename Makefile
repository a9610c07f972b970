# Two commands on a fresh Debian 12 or 13 machine (see README):
#   make demo   installs what is missing, then runs the gelatin-cube demo
#   make test   installs what is missing, then runs the tests on one rank (a file to a core) and under mpirun -n 2
#               (--oversubscribe: two ranks on a one-core machine too)
PY := .venv/bin/python
# Open MPI refuses to run as root without these (containers, CI).
export OMPI_ALLOW_RUN_AS_ROOT := 1
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM := 1
# One thread per MPI rank: the solvers are MPI-parallel, BLAS threads only oversubscribe.
export OMP_NUM_THREADS := 1

.PHONY: install demo test test-serial test-mpi lint format test-debian13 docker bench clean

install:
	@scripts/install.sh

demo: install
	$(PY) demos/cube.py

test: install
	$(MAKE) --no-print-directory test-serial test-mpi

# One worker a core, a test file to a worker (its fixtures built once): the serial suite in
# about half the time on two cores. Each worker is one MPI rank of its own.
test-serial:
	$(PY) -m pytest -q -p no:cacheprovider -n auto --dist loadfile tests

test-mpi:
	mpirun -n 2 --oversubscribe $(PY) -m pytest -q -p no:cacheprovider -m mpi tests

# ruff's lint and format check (rules in pyproject.toml); `make format` rewrites in place.
lint: install
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

format: install
	$(PY) -m ruff check --fix --exit-zero --quiet .
	$(PY) -m ruff format .

# The same suite on DOLFINx 0.9 in a Debian 13 root filesystem (needs root; cached).
test-debian13:
	scripts/debian13.sh make test

# docker/Dockerfile, with the tests and a demo as build steps (docker, or podman as root).
docker:
	scripts/docker-build.sh fenics-brainshift

bench: install
	$(PY) benchmarks/cube_sizes.py
	$(PY) benchmarks/stability.py

clean:
	rm -rf out_* .pytest_cache
