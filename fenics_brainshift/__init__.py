"""fenics-brainshift: intraoperative brain shift from gravity and draining CSF, with DOLFINx."""
__version__ = "0.1.0"
