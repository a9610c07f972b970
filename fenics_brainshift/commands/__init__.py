"""The ``brainshift`` commands, one module each, in the order ``brainshift --help`` lists them.

Every module has ``add(sub)``, which adds its subcommand and arguments to the CLI's parser,
and ``main(args, comm) -> list[str]``, which does the work and returns the lines the CLI
prints on rank 0. The parser of every command is built on each call, so a module imports
nothing at its top that starts DOLFINx or PETSc: those imports sit inside ``main``
(tests/test_layers.py checks it).
"""

NAMES = (
    "run",
    "prepare",
    "mesh",
    "warp",
    "fit",
    "atlas",
    "update",
    "serve",
    "replay",
    "compare",
    "bench",
    "info",
    "scenes",
)
