"""The documentation's examples run as written, and its links point at files that exist."""

from __future__ import annotations

import re

import pytest

from conftest import COMM, ROOT

pytestmark = pytest.mark.mpi
DOCS = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]


@pytest.mark.parametrize("block", range(5))
def test_api_examples_run(block):
    code = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "api.md").read_text(), re.S)
    assert len(code) == 5
    exec(compile(code[block], f"docs/api.md example {block + 1}", "exec"), {})


def test_readme_scene_runs(shared_tmp):
    from fenics_brainshift.cli import main

    toml = re.findall(r"```toml\n(.*?)```", (ROOT / "README.md").read_text(), re.S)[0]
    scene = shared_tmp / "readme.toml"
    if COMM.rank == 0:
        scene.write_text(toml)
    COMM.barrier()
    assert main(["--log-level", "WARNING", "run", str(scene), "--out", str(shared_tmp / "out")]) == 0
    assert (shared_tmp / "out" / "summary.json").is_file()


@pytest.mark.parametrize("page", DOCS, ids=[p.name for p in DOCS])
def test_links_and_paths_exist(page):
    text = page.read_text()
    targets = re.findall(r"\]\(([^)#\s]+)", text)  # markdown links
    targets += [
        t for t in re.findall(r"`((?:fenics_brainshift|benchmarks|demos|scripts|tests|docs|docker)/[^`\s]*)`", text)
    ]
    for target in targets:
        if target.startswith(("http://", "https://")):
            continue
        target = re.sub(r"\{([^,}]*),[^}]*\}", r"\1", target)  # a.{csv,md}: the first is enough
        if "*" in target:
            target = target.rsplit("/", 1)[0]  # a glob: its folder must exist
        base = (
            page.parent
            if not target.startswith(("fenics_brainshift/", "benchmarks/", "demos/", "scripts/", "tests/", "docker/"))
            else ROOT
        )
        path = (base / target).resolve()
        assert path.exists(), f"{page.name}: {target}"
        assert ROOT in path.parents or path == ROOT, f"{page.name}: {target} is outside the repository"


def _written_by(command: str) -> list[str]:
    """The paths a brainshift command line writes (--out, -o, --output, --transform)."""
    words = command.split()
    return [words[i + 1] for i, w in enumerate(words[:-1]) if w in ("--out", "-o", "--output", "--transform")]


def test_the_documented_commands_write_into_their_own_ignored_folders():
    """The README's Slicer, calibration and patient commands wrote T1_intra.nii.gz, warp.h5 and
    patient/ into the repository's root (not ignored by git) and reused the quick start's
    out_brain and out_fit, overwriting them. Every output of a brainshift command in the
    README and the docs lies in an out_* folder (.gitignore: out_*/), and in the README no two
    commands write into the same folder, nor a warp into a run's (a re-run clears only its own
    files: the old warp would sit beside the new run)."""
    ignored = (ROOT / ".gitignore").read_text().splitlines()
    assert "out_*/" in ignored
    folders = {}  # README: top folder -> the command lines writing into it
    for page in DOCS:
        blocks = re.findall(r"```(?:sh|bash)\n(.*?)```", page.read_text(), re.S)
        lines = " ".join(blocks).replace("\\\n", " ").splitlines()
        for line in lines:
            command = line.split("#")[0].strip()
            if not re.match(r"(mpirun -n \d+ )?(\.venv/bin/)?brainshift ", command):
                continue
            for path in _written_by(command):
                top = path.split("/")[0]
                assert re.fullmatch(r"out_[A-Za-z0-9_]+", top), f"{page.name}: '{command}' writes {path}"
                if page.name == "README.md":
                    folders.setdefault(top, set()).add(command)
    shared = {top: sorted(c) for top, c in folders.items() if len(c) > 1}
    assert not shared, shared
