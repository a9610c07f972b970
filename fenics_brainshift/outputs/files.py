"""Small output files written atomically by rank 0 (summary.json, probes.csv), and the check
that an output folder can be written, made before any work."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from .. import json_text
from ..errors import InputError


def check_writable(out: Path, comm, what: str = "output folder", flag: str = "--out") -> None:
    """The folder must be creatable (its nearest existing parent writable) or writable;
    checked on rank 0, raised on every rank."""
    problem = None
    if comm.rank == 0:
        existing = out
        while not existing.exists() and existing != existing.parent:
            existing = existing.parent
        if out.exists() and not out.is_dir():
            problem = f"{what} '{out}' is an existing file; choose another {flag}"
        elif not existing.is_dir() or not _can_create_in(existing):
            problem = f"{what} '{out}' cannot be written ('{existing}' is not a writable folder); choose another {flag}"
    problem = comm.bcast(problem, root=0)
    if problem:
        raise InputError(problem)


def _can_create_in(folder: Path) -> bool:
    """Can a folder be made in ``folder``? Tried, not judged by permission bits: root passes
    os.access everywhere, yet /proc, a read-only mount or a full disk still refuse."""
    import tempfile

    try:
        os.rmdir(tempfile.mkdtemp(prefix=".brainshift-probe-", dir=folder))
    except OSError:
        return False
    return True


# what a run writes into its folder (outputs/xdmf.py, pictures.py, runner/driver.py): cleared
# before a run writes there, so that a re-run never sits beside an earlier run's files
RUN_FILES = (
    "summary.json",
    "probes.csv",
    "probes_final.mrk.json",
    "displacement.xdmf",
    "displacement.h5",
    "last_state.npz",
    "deformed.png",
    "probes.png",
    "surface_final.vtk",
    "surface_final.stl",
    "skull.stl",
)
# the records a fit and an update write beside a run's files (fit/report.py, commands/update.py)
RECORDS = {
    "fit": ("fit.json", "fitted.toml"),
    "update": ("update.json", "uncertainty.nii.gz", "targets_updated.mrk.json", "update.png"),
}
RUN_SERIES = ("surface_[0-9][0-9][0-9][0-9].vtk", "surface_[0-9][0-9][0-9][0-9].stl")


class RunLock:
    """One run at a time in a folder: rank 0 holds an exclusive flock on OUT/.brainshift.lock
    for the whole run (two runs into one --out interleaved their files). The kernel drops the
    lock when the process ends, however it ends: a run killed with SIGKILL leaves no stale lock."""

    NAME = ".brainshift.lock"
    _held: dict = {}  # folder -> how many holders in this process (a fit's run inside the fit)

    def __init__(self, out: Path, comm, flag: str = "--out"):

        self.comm, self._file, problem = comm, None, None
        self._key = str(Path(out).resolve())
        if self._key in RunLock._held:  # this process holds it already: nested, not a second writer
            RunLock._held[self._key] += 1
            return
        if comm.rank == 0:
            f = open(out / self.NAME, "a+")
            try:
                _flock_soon(f)
            except BlockingIOError:
                f.seek(0)
                holder = f.read().strip() or "another process"
                f.close()
                problem = (
                    f"{flag} '{out}': another brainshift process ({holder}) is writing into it; wait for it to "
                    f"end or choose another {flag}"
                )
            else:
                f.seek(0)
                f.truncate()
                f.write(f"pid {os.getpid()}")
                f.flush()
                self._file = f
        problem = comm.bcast(problem, root=0)
        if problem:
            raise InputError(problem)
        RunLock._held[self._key] = 1

    @classmethod
    def holder(cls, out: Path) -> str | None:
        """Which process holds OUT's lock ("pid N"), or None when none does: a folder whose
        summary.json says "running" with no holder was left by a run that was killed."""
        import fcntl

        try:
            f = open(Path(out) / cls.NAME)
        except OSError:
            return None
        with f:
            try:
                fcntl.flock(f, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except BlockingIOError:
                return f.read().strip() or "another process"
            return None

    def release(self) -> None:
        count = RunLock._held.pop(self._key, 0)
        if count > 1:
            RunLock._held[self._key] = count - 1
            return
        if self._file is not None:
            self._file.close()  # (closing drops the flock)
            self._file = None


def _flock_soon(f) -> None:
    """The exclusive lock, tried for a quarter second: RunLock.holder's probe (a warp asking
    whether a run is alive) holds a shared lock for an instant, and is no writer."""
    import fcntl
    import time

    for attempt in range(6):
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return
        except BlockingIOError:
            if attempt == 5:
                raise
            time.sleep(0.05)


def clear_run(out: Path, comm, scene_name: str, keep=(), kind: str = "run", overwrite: bool = False) -> None:
    """Remove an earlier run's files from ``out`` (only those a run writes, and for a fit or an
    update its own earlier record; not the files in ``keep``), then mark the folder's
    summary.json "running": a run killed from here on never leaves the earlier run's "ok"
    beside its own partial files. A folder holding another kind's record is refused first,
    naming it: a run beside a fit's record would mix the two, and removing the record would
    lose the user's fit (a run of the folder's own fitted.toml, in ``keep``, is the fit's);
    so is a run's folder for an update, which would replace the run's results. With
    ``overwrite`` (the commands' --overwrite) nothing is refused: every kind's files go."""
    problem = None
    kept = {Path(p).resolve() for p in keep}
    if comm.rank == 0 and not overwrite:
        for other, names in RECORDS.items():
            if other == kind or not (out / names[0]).is_file():
                continue
            if other == "fit" and kind == "run" and (out / "fitted.toml").resolve() in kept:
                continue  # the fit's own scene, run where it was fitted
            article = "an" if other == "update" else "a"
            problem = f"--out '{out}' holds {article} {other} ({names[0]}): " + (
                "run its fitted.toml there, choose another --out, or --overwrite to replace it"
                if other == "fit"
                else "choose another --out, or --overwrite to replace it"
            )
        if problem is None and kind == "update":
            problem = runs_results(out)
    problem = comm.bcast(problem, root=0)
    if problem:
        raise InputError(problem)
    if comm.rank == 0:
        names = RUN_FILES + (sum(RECORDS.values(), ()) if overwrite else RECORDS.get(kind, ()))
        for path in [out / name for name in names] + [p for pattern in RUN_SERIES for p in out.glob(pattern)]:
            if path.is_file() and path.resolve() not in kept:
                path.unlink()
    running = {"scene": scene_name, "status": "running"} | ({"kind": kind} if kind != "run" else {})
    write_json(out / "summary.json", running, comm)


def runs_results(out: Path) -> str | None:
    """Why an update may not write into ``out``: it holds a run's results, which the update would
    replace (a fit clears its folder's run on purpose: the fitted scene's run takes its place);
    an update's own folder, even one interrupted before its update.json, is not refused."""
    found = [name for name in RUN_FILES if name != "summary.json" and (out / name).is_file()]
    found += sorted(p.name for pattern in RUN_SERIES for p in out.glob(pattern))[:1]
    if not found or (out / RECORDS["update"][0]).is_file():
        return None
    try:
        kind = json.loads((out / "summary.json").read_text()).get("kind")
    except (OSError, ValueError, AttributeError):
        kind = None
    if kind == "update":
        return None
    return (
        f"--out '{out}' holds a run's results ({', '.join(found[:3])}) that the update would "
        f"replace: choose another --out, or --overwrite to replace them"
    )


def record_holding(path: Path) -> str | None:
    """What a file belongs to, when writing over it would lose another command's results: one
    of a run's, a fit's or an update's own files in a folder with a summary.json ("a run's
    displacement.h5"); None for any other file."""
    path = Path(path)
    if not (path.parent / "summary.json").is_file():
        return None
    if path.name in RUN_FILES or any(path.match(pattern) for pattern in RUN_SERIES):
        return f"a run's {path.name}"
    for kind, names in RECORDS.items():
        if path.name in names:
            return f"a{'n' if kind == 'update' else ''} {kind}'s {path.name}"
    return None


def check_output_file(path: Path, flag: str, command: str, inputs=(), overwrite: bool = False) -> None:
    """An output file's name, judged before any work: not an existing folder; and, unless
    ``overwrite`` (the command's --overwrite), not one of the command's own ``inputs`` (the
    image being warped) nor a file of a run's, a fit's or an update's results, which writing
    there would lose."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{command}: {flag} '{path}' is a folder; give a file name in it")
    if overwrite or not path.exists():
        return
    for given, name in inputs:
        if Path(given).exists() and path.resolve() == Path(given).resolve():
            raise InputError(
                f"{command}: {flag} '{path}' is the {name} it reads: writing there would lose it; choose another "
                f"{flag} (or --overwrite)"
            )
    held = record_holding(path)
    if held is not None:
        raise InputError(
            f"{command}: {flag} '{path}' is {held}: writing there would lose it; choose another {flag} (or --overwrite)"
        )


def write_json(path: Path, data: dict, comm) -> None:
    """Written by rank 0 via a temporary file and a rename: never half a file."""
    if comm.rank == 0:
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(json_text.dumps(data) + "\n")
        os.replace(tmp, path)
    comm.barrier()


def write_csv(path: Path, header: list[str], rows: list[list[float]], comm) -> None:
    """A CSV of numbers with a header line, written by rank 0 via a temporary file."""
    if comm.rank == 0:
        tmp = path.with_suffix(".csv.tmp")
        np.savetxt(
            tmp,
            np.array(rows, dtype=float).reshape(-1, len(header)),
            delimiter=",",
            header=",".join(header),
            comments="",
            fmt="%.10g",
        )
        os.replace(tmp, path)
    comm.barrier()
