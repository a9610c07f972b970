"""The package's house rules, checked on its source: its folders import one way only (the
layers of docs/layout.md), and the theatre path (the update, the markups, target and surface
readers, the CLI's parser) starts neither DOLFINx nor PETSc."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import subprocess_env

PACKAGE = Path(__file__).resolve().parents[1] / "fenics_brainshift"

# Lowest first. A folder imports from lower layers only; the ground's modules also from each
# other (they form no cycle: checked below). The ground starts no DOLFINx; compat.py is the
# first layer that does. The package's __init__ (the lazy public API) sits on top with cli.py.
LAYERS = [
    {"version", "errors", "logs", "units", "formats", "json_text", "data", "memory"},
    {"surfaces"},
    {"images"},
    {"scene"},
    {"compat"},
    {"meshing", "linalg"},
    {"physics"},
    {"stepping"},
    {"outputs"},
    {"runner"},
    {"fit", "warp", "bench"},
    {"atlas", "patients", "machine"},
    {"theatre"},
    {"commands"},
    {"cli", "__init__"},
]
LAYER = {name: i for i, names in enumerate(LAYERS) for name in names}

THEATRE = [
    "fenics_brainshift.atlas.update",
    "fenics_brainshift.atlas.update_picture",
    "fenics_brainshift.atlas.store",
    "fenics_brainshift.outputs.files",
    "fenics_brainshift.outputs.run_folder",
    "fenics_brainshift.images.volumes",
    "fenics_brainshift.images.rasterize",
    "fenics_brainshift.images.frames",
    "fenics_brainshift.images.targets",
    "fenics_brainshift.surfaces",
    "fenics_brainshift.commands.update",
    "fenics_brainshift.theatre.case",
    "fenics_brainshift.theatre.session",
    "fenics_brainshift.theatre.server",
    "fenics_brainshift.theatre.record",
    "fenics_brainshift.commands.serve",
    "fenics_brainshift.commands.replay",
]


def _folder(module: str) -> str:
    """'fenics_brainshift.atlas.update' -> 'atlas'; a top-level module is its own folder."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _module_or_package(base: list[str], name: str) -> str:
    where = PACKAGE.parent.joinpath(*base, name)
    return ".".join(base + [name]) if where.is_dir() or where.with_suffix(".py").is_file() else ".".join(base)


def _imports(path: Path) -> list[tuple[str, int]]:
    """(imported module, line) of every import of the package in a source file, those inside
    functions too (a lazy import is still a dependency)."""
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    package = list(rel.parts[:-1]) if rel.name != "__init__" else list(rel.parts[:-1])
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                if node.module:
                    found.append((".".join(base + [node.module]), node.lineno))
                else:  # from . import a, b: modules of the package, or names its __init__ defines
                    found += [(_module_or_package(base, a.name), node.lineno) for a in node.names]
            elif node.module == PACKAGE.name:  # from fenics_brainshift import runner: the module named
                found += [(_module_or_package([PACKAGE.name], a.name), node.lineno) for a in node.names]
            elif node.module and node.module.split(".")[0] == PACKAGE.name:
                found.append((node.module, node.lineno))
        elif isinstance(node, ast.Import):
            found += [(a.name, node.lineno) for a in node.names if a.name.split(".")[0] == PACKAGE.name]
        elif isinstance(node, ast.Call) and _called(node) == "import_module" and node.args:
            name = _literal_start(node.args[0])  # (an f-string: its constant start, ".commands.")
            if name.startswith("."):
                level = len(name) - len(name.lstrip("."))
                rest = name.lstrip(".").rstrip(".")
                base = package[: len(package) - (level - 1)]
                found.append((".".join(base + ([rest] if rest else [])), node.lineno))
            elif name.split(".")[0] == PACKAGE.name:
                found.append((name.rstrip("."), node.lineno))
    return found


def _called(call: ast.Call) -> str:
    func = call.func
    return func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else ""


def _literal_start(node: ast.AST) -> str:
    """A string literal's text, or an f-string's constant start ("" when it has none)."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr) and node.values and isinstance(node.values[0], ast.Constant):
        return str(node.values[0].value)
    return ""


def _edges() -> list[tuple[str, str, str]]:
    """(importing folder, imported folder, 'file:line') across folders."""
    out = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        here = _folder(".".join(rel.parts))
        for module, line in _imports(path):
            there = _folder(module)
            if there != here:
                out.append((here, there, f"{path.relative_to(PACKAGE.parent)}:{line}"))
    return out


def test_every_folder_has_a_layer():
    folders = {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    modules = {p.stem for p in PACKAGE.glob("*.py")}
    assert folders | modules == set(LAYER), "add the new folder or module to LAYERS (and to docs/layout.md)"


def test_folders_import_downwards_only():
    wrong = [
        f"{where}: {here} imports {there}"
        for here, there, where in _edges()
        if LAYER[there] > LAYER[here] or (LAYER[there] == LAYER[here] and LAYER[here] > 0)
    ]
    assert not wrong, "\n".join(wrong)


def test_the_ground_has_no_cycle():
    ground = {}
    for here, there, _ in _edges():
        if LAYER[here] == LAYER[there] == 0:
            ground.setdefault(here, set()).add(there)

    def reaches(start, goal, seen=()):
        return any(n == goal or (n not in seen and reaches(n, goal, (*seen, n))) for n in ground.get(start, ()))

    assert not [m for m in ground if reaches(m, m)]


@pytest.mark.usefixtures("serial_only")
def test_the_theatre_path_starts_neither_dolfinx_nor_petsc():
    code = (
        "import sys\n"
        + "".join(f"import {m}\n" for m in THEATRE)
        + "import fenics_brainshift.cli as cli\ncli.parser()\n"
        + "print(sorted(m for m in ('dolfinx', 'petsc4py', 'ufl', 'basix', 'ffcx') if m in sys.modules))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=subprocess_env(), timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_every_command_module_adds_its_parser_and_has_a_main():
    import importlib

    from fenics_brainshift.commands import NAMES

    files = {p.stem for p in (PACKAGE / "commands").glob("*.py")} - {"__init__", "help_format"}
    assert files == set(NAMES)
    for name in NAMES:
        module = importlib.import_module(f"fenics_brainshift.commands.{name}")
        assert callable(module.add) and callable(module.main)


def _public() -> list[tuple[str, str, object]]:
    """(package, name, object) of every name a package exports in its __all__."""
    import importlib
    import pkgutil

    import fenics_brainshift

    packages = ["fenics_brainshift"] + [
        f"fenics_brainshift.{m.name}" for m in pkgutil.iter_modules(fenics_brainshift.__path__) if m.ispkg
    ]
    out = []
    for name in packages:
        module = importlib.import_module(name)
        out += [(name, n, getattr(module, n)) for n in getattr(module, "__all__", []) if n != "__version__"]
    return out


def test_the_public_api_is_typed_and_documented():
    """Every exported function has its parameters and its return typed and a docstring; every
    exported class a docstring of its own (not a dataclass's generated signature)."""
    import inspect

    wrong = []
    for package, name, obj in _public():
        doc = obj.__doc__ if inspect.isclass(obj) else inspect.getdoc(obj)
        if not doc or doc.startswith(f"{name}("):
            wrong.append(f"{package}.{name}: no docstring")
        if inspect.isfunction(obj):
            signature = inspect.signature(obj)
            untyped = [p for p, v in signature.parameters.items() if v.annotation is inspect.Parameter.empty]
            if untyped or signature.return_annotation is inspect.Signature.empty:
                wrong.append(f"{package}.{name}: untyped {untyped or 'return'}")
    assert not wrong, "\n".join(wrong)


def test_the_layout_page_names_every_folder_and_module():
    """docs/layout.md's map of the package: each folder's entry names each of its modules, and
    the page names no module that is not there."""
    import re

    page = (PACKAGE.parent / "docs" / "layout.md").read_text()
    tree = page[page.index("fenics_brainshift/\n") :]
    tree = tree[: tree.index("```")]
    entries, current = {}, None
    for line in tree.splitlines()[1:]:
        head = re.match(r"^  (\S+)", line)
        if head:
            current = head.group(1).rstrip("/")
        if current:
            entries[current] = entries.get(current, "") + " " + line
    for folder in sorted(p for p in PACKAGE.iterdir() if (p / "__init__.py").exists()):
        assert folder.name in entries, f"docs/layout.md: no entry for {folder.name}/"
        named = set(re.findall(r"\b(\w+)\.py\b", entries[folder.name]))
        modules = {p.stem for p in folder.glob("*.py")} - {"__init__"}
        assert modules <= named, f"docs/layout.md: {folder.name}/ misses {sorted(modules - named)}"
        assert named <= modules, f"docs/layout.md: {folder.name}/ names {sorted(named - modules)}, not in the tree"
    for module in PACKAGE.glob("*.py"):
        assert module.name in entries, f"docs/layout.md: no entry for {module.name}"


def test_no_export_hides_a_module():
    """A folder that exported a function named as one of its modules (atlas's ``update``) made
    ``import fenics_brainshift.atlas.update as m`` return the function."""
    hidden = [
        f"{package}.{name}"
        for package, name, _ in _public()
        if (PACKAGE.parent.joinpath(*package.split("."), f"{name}.py")).exists()
    ]
    assert not hidden, hidden
