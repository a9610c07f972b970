"""From a patient's pre-operative T1 to a scene: `brainshift prepare` (docs/patients.md).

series.py reads the T1 (a DICOM series, NIfTI or NRRD) with SimpleITK; registration.py finds
the map from the patient's frame to the ICBM152 template's (rigid, affine, B-spline);
carry.py moves labels and points through it; anatomy.py holds what the bundled brain scene
defines in the template's frame (supports, septa, probes); position.py turns a head position
and a craniotomy into gravity and a CSF level; prepare.py writes the patient's folder
(`brainshift prepare`: commands/prepare.py).
"""
