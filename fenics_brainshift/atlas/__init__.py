"""Model-updated guidance: an atlas of settled states computed before surgery
(``brainshift atlas``: build.py), and the combination of them that fits what is measured once
the dura is open (``brainshift update``: update.py). docs/update.md shows the workflow.

The theatre path imports neither DOLFINx nor PETSc (tests/test_layers.py)::

    from fenics_brainshift.atlas import read_atlas
    from fenics_brainshift.atlas.update import prepare, update
    from fenics_brainshift.images.targets import read_target

    atlas = read_atlas("out_atlas")
    prepare(atlas)                                   # once, when the atlas is loaded
    result = update(atlas, read_target("points.mrk.json"), noise=1e-3)
    result.displacement                              # (nodes, 3) m at atlas.points

(The functions stay in atlas.update: exported here, ``update`` would hide that module.)
"""

from .store import Atlas
from .store import read as read_atlas
from .update import UpdateResult

__all__ = ["Atlas", "UpdateResult", "read_atlas"]
