"""Write meshes/phantom_ellipsoid_mm.msh: a brain-sized ellipsoid in millimetres.

Semi-axes 70 (left-right) x 85 (posterior-anterior) x 60 (inferior-superior) mm, about the
size of an adult brain, centred so the lowest point is at z = 0; element size 12 mm. It is a
stand-in until the real brain mesh (built from the MNI template) ships, and the example of a
mesh file in mm (`[mesh] unit = "mm"`).

    .venv/bin/python scripts/make_phantom.py
"""

from pathlib import Path

import gmsh

OUT = Path(__file__).resolve().parents[1] / "meshes" / "phantom_ellipsoid_mm.msh"
A, B, C, H = 70.0, 85.0, 60.0, 12.0

gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
gmsh.model.add("phantom")
tag = gmsh.model.occ.addSphere(0.0, 0.0, C, 1.0)
gmsh.model.occ.dilate([(3, tag)], 0.0, 0.0, C, A, B, C)
gmsh.model.occ.synchronize()
gmsh.model.addPhysicalGroup(3, [tag], 1)
gmsh.option.setNumber("Mesh.CharacteristicLengthMin", H)
gmsh.option.setNumber("Mesh.CharacteristicLengthMax", H)
gmsh.model.mesh.generate(3)
gmsh.option.setNumber("Mesh.Binary", 0)
gmsh.write(str(OUT))
gmsh.finalize()
print(f"wrote {OUT} ({OUT.stat().st_size // 1024} KiB)")
