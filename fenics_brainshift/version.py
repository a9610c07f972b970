"""The release: one number, which the package, `brainshift --version`, `brainshift info`, the
wheel's metadata and the Docker image's label show (tests/test_install.py)."""

__version__ = "0.3.0"
