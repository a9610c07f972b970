"""`brainshift serve ATLAS`: the live service in theatre (theatre/): the atlas held prepared,
OpenIGTLink clients (3D Slicer's OpenIGTLinkIF, a navigation system) send points and get the
updated brain back in milliseconds; docs/theatre.md walks through it."""

from __future__ import annotations

import signal
import time
from pathlib import Path

from ..errors import InputError
from .help_format import Defaults

ONE_PROCESS = True  # (the CLI starts no MPI for it; launched by mpirun it refuses)


def add(sub) -> None:
    serve = sub.add_parser(
        "serve",
        formatter_class=Defaults,
        help="in theatre, live: an OpenIGTLink server holding the atlas; points in, the updated brain out",
        description="Hold the atlas prepared and serve OpenIGTLink clients: a POINT list (Slicer's markups) "
        "replaces the case's points and starts an update (labels among --pre point to point, the rest point "
        "to surface), a TRANSFORM/POSITION tip is captured on the STRING 'capture' or when it rests, a "
        "POLYDATA is a surface scan; STRING commands: update, capture, undo, reset, status. Each update "
        "answers with the moved cortex (POLYDATA BrainshiftCortex), the moved targets and pre-operative "
        "points (POINT), the displacement and its uncertainty on a grid (IMAGE BrainshiftShift, "
        "BrainshiftSpread), the next point worth touching (POINT NextPoint) and the status (STRING "
        "BrainshiftStatus, JSON) last. Runs until Ctrl-C.",
    )
    serve.add_argument("atlas", help="atlas folder (brainshift atlas SCENE -o ATLAS)")
    serve.add_argument(
        "--port", type=int, default=18944, help="TCP port (OpenIGTLink's own is 18944; 0: any free one, said at start)"
    )
    serve.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on; anything but loopback puts the port on a network (OpenIGTLink has no "
        "authentication: the navigation network only, with --allow)",
    )
    serve.add_argument("--allow", action="append", default=[], help="a client address allowed (repeat); default any")
    serve.add_argument("--pre", help="the pre-operative points (.mrk.json): point-list labels among them are pairs")
    serve.add_argument(
        "--targets",
        help="points of interest (.mrk.json: the tumour's margin): moved, and where suggestions aim "
        "(default: the atlas's probes)",
    )
    serve.add_argument(
        "--structure",
        action="append",
        default=[],
        metavar="NAME=FILE",
        help="a segmented structure's surface (.stl, .vtk, .ply, ... in mm; a tumour, the ventricles) moved with "
        "each update and sent as POLYDATA BrainshiftNAME (repeat; NAME: letters and digits, at most 10)",
    )
    serve.add_argument(
        "--frame", type=str.upper, choices=["RAS", "LPS"], default="RAS", help="the clients' frame (Slicer: RAS)"
    )
    serve.add_argument("--noise", type=float, default=1.0, help="a point's measurement noise, mm per coordinate")
    serve.add_argument("--grid", type=float, default=4.0, help="the displacement image's spacing, mm (0: none)")
    serve.add_argument("--share", action="store_true", help="every client updates one case (else one each)")
    serve.add_argument(
        "--stage",
        type=int,
        default=0,
        help="an atlas with resection stages (atlas --resect): the stage to serve (0: before the resection; "
        "`brainshift update` chooses among them)",
    )
    serve.add_argument(
        "--record", help="a folder to append every message received and every update sent to (resumed on a restart)"
    )
    serve.add_argument("--seconds", type=float, default=0.0, help="stop after this long (0: at Ctrl-C); for scripts")


def main(args, comm) -> list[str]:
    """Serve until Ctrl-C (or --seconds); returns the closing line."""
    started = time.perf_counter()
    if comm.size > 1 or under_mpirun():
        raise InputError("serve: run it as one process (the update is milliseconds; mpirun adds nothing)")
    if not 0 <= args.port < 65536:
        raise InputError(f"--port: {args.port} is not a TCP port (1-65535; 0: any free one)")
    if args.seconds < 0:
        raise InputError(f"--seconds: {args.seconds} is negative")
    from ..images.targets import check_noise

    check_noise(args.noise, "--noise")
    make, options = session_factory(args)
    from ..theatre.server import Server, loopback

    recorder, resumed = None, (None, None)
    if args.record:
        from ..theatre.record import Recorder

        resumed = resume(Path(args.record), make, options)
        recorder = Recorder(Path(args.record), options, resumed[0])
    server = Server(lambda: make(resumed[1]), args.host, args.port, args.allow, recorder, log=_log)
    if not loopback(args.host):
        _log(
            f"WARNING: listening on {args.host}, not loopback: OpenIGTLink has no authentication; keep port "
            f"{server.port} on the navigation network only"
            + ("" if args.allow else " and name the clients with --allow")
        )
    _log(
        f"serving {args.atlas}{f' (resection stage {args.stage})' if args.stage else ''} on {args.host}:"
        f"{server.port} ({args.frame}, mm), ready in "
        f"{time.perf_counter() - started:.2f} s; Ctrl-C to stop"
    )
    stop = {"now": False}
    signal.signal(signal.SIGTERM, lambda *_: stop.update(now=True))
    ends = started + args.seconds if args.seconds else float("inf")
    until = lambda: stop["now"] or time.perf_counter() > ends  # noqa: E731
    try:
        server.serve(until)
    except KeyboardInterrupt:
        pass
    finally:
        if recorder is not None:
            recorder.close()
    return [f"serve: stopped after {server.updates} updates"]


def under_mpirun() -> bool:
    """Launched by mpirun with more than one process (Open MPI's or MPICH's environment)."""
    import os

    return any(int(os.environ.get(k, "1") or 1) > 1 for k in ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE"))


def session_factory(args):
    """(new_session(case=None), the options a record keeps): the atlas read and prepared once,
    the case's pre-operative points and targets; each client a case of its own (beginning
    with the points of `case`, a resumed one), or with --share one case for a start's clients."""
    import hashlib

    from ..atlas import store
    from ..images.frames import read_markups
    from ..theatre.case import Case
    from ..theatre.session import Session

    atlas = store.read(args.atlas)
    stage = getattr(args, "stage", 0)
    if stage < 0:
        raise InputError(f"--stage {stage}: stages are numbered 0 (before the resection), 1, 2, ...")
    atlas_id = atlas.info.get("build_id") or atlas.mesh_id()  # (the folder's atlas; the stage is its own option)
    if stage:
        atlas = store.read_stage(args.atlas, atlas, stage)
    atlas.vertex_modes.hold()  # (every mode read, checked and kept in memory for the operation: mode_file.py)
    pre = targets = None
    digest = {}
    for name in ("pre", "targets"):
        path = getattr(args, name)
        if path:
            labels, mm = read_markups(path, f"--{name}")
            digest[name] = hashlib.sha256(repr((labels, mm.round(6).tolist())).encode()).hexdigest()[:16]
            if name == "pre":
                pre = (labels, mm * 1e-3)
            else:
                targets = (labels, mm * 1e-3)
    if args.grid and not 0.5 <= args.grid <= 20:
        raise InputError(f"--grid: {args.grid:g} mm; the displacement image's spacing is 0.5-20 mm (0: none)")
    structures = read_structures(getattr(args, "structure", []) or [])
    for name, (points, triangles) in structures.items():
        digest[f"structure {name}"] = hashlib.sha256(points.round(9).tobytes() + triangles.tobytes()).hexdigest()[:16]
    base = Case(
        atlas,
        pre,
        targets,
        noise=args.noise * 1e-3,
        grid=args.grid * 1e-3 if args.grid else None,
        structures=structures,
    )
    shared: dict = {}

    def new_session(case=None):
        if not args.share:
            return Session(base.fresh(case), args.frame)
        if id(case) not in shared:  # (one case for the clients of a start, kept with what it began from)
            shared[id(case)] = (case, base.fresh(case))
        return Session(shared[id(case)][1], args.frame)

    options = {"frame": args.frame, "noise": args.noise, "grid": args.grid, "share": bool(args.share), **digest}
    options["atlas"] = atlas_id
    options["stage"] = stage
    return new_session, options


def read_structures(items: list[str]) -> dict:
    """--structure NAME=FILE ... -> {NAME: (points m RAS, triangles)}."""
    import re

    from ..surfaces.files import read_surface

    out = {}
    for item in items:
        name, _, path = item.partition("=")
        if not re.fullmatch(r"[A-Za-z0-9]{1,10}", name) or not path:
            raise InputError(
                f"--structure {item!r}: give NAME=FILE, NAME letters and digits, at most 10 (it names the POLYDATA "
                f"Brainshift<NAME>)"
            )
        if name in out:
            raise InputError(f"--structure: {name} given twice")
        if not Path(path).is_file():
            raise InputError(f"--structure {name}: no file '{path}'")
        out[name] = read_surface(Path(path), 1e-3)
    return out


def resume(folder: Path, new_session, options: dict | None = None) -> tuple[int | None, object]:
    """(client, its case): the client of a record whose last good update came last, whose case
    every new client begins with; (None, None) for a new record."""
    if folder.is_dir() and (folder / "messages.bin").is_file():
        from ..theatre.record import play, repair

        note = repair(folder)
        if note:
            _log(f"--record: {note}")
        from ..theatre.record import options_of

        before = options_of(folder) or {}
        changed = [k for k in before if options is not None and before[k] != options.get(k)]
        if changed:  # (a record replays with one set of options)
            k = changed[0]
            raise InputError(
                f"--record '{folder}': the operation there was served with {k} {before[k]!r}, not {options.get(k)!r}: "
                f"give the same options, or another folder"
            )
        sessions, _, last, _ = play(folder, new_session, answer=False)
        if last in sessions:
            _log(f"resumed the recorded case of client {last}: {sessions[last].case.counts}")
            return last, sessions[last].case
    return None, None


def _log(line: str) -> None:
    """A line of the service's log (the package's logger: stderr, --log-level), with the time."""
    from ..logs import get_logger

    get_logger("serve").info(f"[{time.strftime('%H:%M:%S')}] {line}")
