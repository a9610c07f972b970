"""Outputs: the XDMF time series (xdmf.py), probes and surface means (probes.py), the fine
surface that follows the model (fine_surface.py), summary files (files.py), pictures
(pictures.py, run in a child process: VTK and DOLFINx do not share one) and the paper's error
measures (metrics.py). Nothing is imported here, so pictures.py loads without DOLFINx."""
