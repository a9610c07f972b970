"""Real clinical scans through `brainshift prepare`, and on through the default atlas, an update
from synthetic pointer points, and the warp: success, the brain found, the quality gate's
numbers and the time of each step, per case, on one core.

The scans are public and not shipped (their sources, paths and commits: CASES below and
docs/patients.md); put them under DATA as CASES names them. For each prepared case the gate's
numbers are also measured with the registration deliberately moved (10 mm along each axis in
turn, and turned 10 degrees about each axis): what a failed registration scores, against which
prepare's thresholds (patients/gate.py MIN_RATIO, MIN_PEAK) are set.

    OMP_NUM_THREADS=1 python benchmarks/prepare_cases.py --data DATA [--cases vs001,chris_t1] [--chain [--ranks 2]]

--chain: also (after prepare, or on the folder an earlier call prepared) `brainshift run` of a
synthetic operation (the scene drained 12 mm further, the brain 0.8 times as stiff), the default
`brainshift atlas` (5 mm), `brainshift update` from 20 cortex points of the operation near the
craniotomy plus 0.5 mm noise, and `brainshift warp` of the T1 by the update; the update's and
the scene's error against the operation on the cortex near the craniotomy; --ranks N builds the
atlas under `mpirun -n N` (its modes shared among the ranks). Each case writes
benchmarks/results/prepare_cases/NAME.json;
--report merges them into benchmarks/results/prepare_cases.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
RESULTS = ROOT / "benchmarks" / "results" / "prepare_cases"
BRAINSHIFT = [str(Path(sys.executable).with_name("brainshift"))]

# name: (path under DATA, extra prepare arguments, what it is, where it is public)
CASES = {
    "vs001_t1c": (
        "t1gd_tumour/VS-SEG-001_ceT1_dicom",
        ["--tumour", "SEG"],
        "post-contrast 3D T1 (MPRAGE), 512 x 512 x 120 at 0.41 x 0.41 x 1.5 mm, vestibular schwannoma, "
        "stereotactic fiducials",
        "TCIA Vestibular-Schwannoma-SEG VS-SEG-001 (CC BY 4.0), as niivue/niivue-demo-images dicom/",
    ),
    "tcga_t1c": (
        "t1gd_tumour/pyradiomics_brain1_TCGA-02-0003_T1post.nrrd",
        ["--tumour", "t1gd_tumour/pyradiomics_brain1_label.nrrd", "--craniotomy", "tumour"],
        "post-contrast 2-D axial T1, 256 x 256 x 25 at 0.78 x 0.78 x 6.5 mm, glioblastoma",
        "TCIA TCGA-GBM TCGA-02-0003, as AIM-Harvard/pyradiomics data/brain1_image.nrrd, brain1_label.nrrd",
    ),
    "glioma2_t1c": (
        "t1gd_tumour/pyradiomics_brain2_T1post.nrrd",
        [
            "--tumour",
            "t1gd_tumour/pyradiomics_brain2_label.nrrd",
            "--craniotomy",
            "tumour",
            "--position",
            "craniotomy-up",
        ],
        "post-contrast 2-D axial T1, 256 x 256 x 23 at 0.78 x 0.78 x 6.5 mm, a small lesion",
        "AIM-Harvard/pyradiomics data/brain2_image.nrrd, brain2_label.nrrd",
    ),
    "trio_t1": (
        "t1_native/trio_b17_t1_MPRAGEcr_noGRAPPA_19_dicom",
        [],
        "native 3D T1 (MPRAGE), 256 x 256 x 176 at 1 mm, sagittal, volunteer",
        "dcm2nii sample images, as CBICA/NiChart_Project test_data/dicoms/trio_b17/t1_MPRAGEcr_noGRAPPA_19",
    ),
    "chris_t1": (
        "t1_native/chris_t1.nii.gz",
        [],
        "native 3D T1, 188 x 256 x 190 at 0.88 mm, volunteer (the head of chris_pd)",
        "niivue/niivue-demo-images chris_t1.nii.gz (CC BY-NC 4.0)",
    ),
    "chris_pd": (
        "t2_flair_pd/chris_PD.nii.gz",
        [],
        "proton density, 191 x 256 x 54 at 0.86 x 0.86 x 2.4 mm, oblique, vertex to skull base (the head of chris_t1)",
        "niivue/niivue-demo-images chris_PD.nii.gz (CC BY-NC 4.0)",
    ),
    "ixi012_t1": (
        "t1_native/IXI012-HH-1211_T1_2mm.nii.gz",
        [],
        "native T1 at 2 mm, 120 x 120 x 90, IXI volunteer",
        "IXI (CC BY-SA 3.0), as CBICA/NiChart_Project test_data/nifti/IXI_Small/t1",
    ),
    "fg6692_t1c": (
        "same_head/fg6692_t1c.nii.gz",
        ["--contrast", "t1c"],
        "post-contrast 2-D axial T1 (spin echo), 256 x 224 x 26 at 0.9 x 0.9 x 5.5 mm, glioma (the head of fg6692_t2)",
        "TCIA TCGA-FG-6692 (a TCGA glioma), as BrainLesion/preprocessing example/example_data/OtherEXampleFromTCIA "
        "MRHR_T1_AX_POST_GAD_..._t1c.nii.gz",
    ),
    "fg6692_t2": (
        "same_head/fg6692_t2.nii.gz",
        ["--contrast", "t2"],
        "2-D axial T2 (TSE), 224 x 256 x 26 at 0.9 x 0.9 x 5.5 mm, glioma (the head of fg6692_t1c)",
        "TCIA TCGA-FG-6692 (a TCGA glioma), as BrainLesion/preprocessing example/example_data/OtherEXampleFromTCIA "
        "MRHR_T2_AX_..._t2.nii.gz",
    ),
    "t2w": (
        "t2_flair_pd/niivue_register_T2w.nii.gz",
        [],
        "2-D T2 (TSE), 224 x 224 x 60 at 1 x 1 x 2 mm, vertex to skull base",
        "niivue/niivue-demo-images register/T2w.nii.gz",
    ),
}
SAME_HEAD = [("chris_t1", "chris_pd"), ("fg6692_t1c", "fg6692_t2")]  # two contrasts of one head: their brains
MOVES = [("x", 10.0, 0.0), ("y", 10.0, 0.0), ("z", 10.0, 0.0), ("x", 0.0, 10.0), ("y", 0.0, 10.0), ("z", 0.0, 10.0)]


def brainshift(argv: list[str], log: Path, ranks: int = 1) -> tuple[int, float]:
    began = time.perf_counter()
    launch = ["mpirun", "-n", str(ranks), "--oversubscribe"] if ranks > 1 else []
    with open(log, "a") as out:
        out.write(f"$ {' '.join(launch)}{' ' if launch else ''}brainshift {' '.join(argv)}\n")
        out.flush()
        code = subprocess.call(
            launch + BRAINSHIFT + argv,
            stdout=out,
            stderr=subprocess.STDOUT,
            cwd=ROOT,
            env={**os.environ, "OMP_NUM_THREADS": "1"},
        )
    return code, time.perf_counter() - began


def gate_when_moved(folder: Path) -> list[dict]:
    """The gate's correlation ratio (fit_measures.fit_measures: the deep brain) with the found
    registration moved (MOVES), and as found."""
    import SimpleITK as sitk

    from fenics_brainshift.data.templates import mni_t1
    from fenics_brainshift.patients.fit_measures import fit_measures
    from fenics_brainshift.patients.registration import Registration

    patient = sitk.ReadImage(str(folder / "t1.nii.gz"), sitk.sitkFloat32)
    template = sitk.ReadImage(str(mni_t1()), sitk.sitkFloat32)
    brain = sitk.GetArrayFromImage(sitk.ReadImage(str(folder / "labels.nii.gz"))) > 0
    found = sitk.ReadTransform(str(folder / "patient_to_template.h5"))
    centre = patient.TransformContinuousIndexToPhysicalPoint([(n - 1) / 2 for n in patient.GetSize()])
    out = [
        {
            "move": "none",
            "correlation_ratio": round(
                fit_measures(patient, template, Registration(found, sitk.AffineTransform(3), patient), brain)["ratio"],
                4,
            ),
        }
    ]
    for axis, shift, angle in MOVES:
        move = sitk.Euler3DTransform()
        move.SetCenter(centre)
        e = np.eye(3)["xyz".index(axis)]
        move.SetTranslation((shift * e).tolist())
        move.SetRotation(*(np.radians(angle) * e).tolist())
        total = sitk.CompositeTransform([found, move])  # the patient point moved first
        measures = fit_measures(patient, template, Registration(total, sitk.AffineTransform(3), patient), brain)
        out.append(
            {
                "move": f"{shift:g} mm along {axis}" if shift else f"{angle:g} deg about {axis}",
                "correlation_ratio": round(measures["ratio"], 4),
            }
        )
    return out


def carried_both_ways(folder: Path) -> dict:
    """The template's brain mask carried onto the scan's grid through the registration itself
    (the B-spline at every voxel) and through its displacement field sampled on 2 mm
    (Registration.sampled, what prepare uses): times and the voxels that differ."""
    import SimpleITK as sitk

    from fenics_brainshift.data.templates import mni_brain_mask
    from fenics_brainshift.patients.registration import Registration

    patient = sitk.ReadImage(str(folder / "t1.nii.gz"), sitk.sitkFloat32)
    transform = sitk.ReadTransform(str(folder / "patient_to_template.h5"))
    grid = sitk.Image(patient.GetSize(), sitk.sitkUInt8)
    grid.CopyInformation(patient)
    mask = sitk.ReadImage(str(mni_brain_mask()))
    out = {}
    for name, through in (
        ("exact", lambda: transform),
        ("field", lambda: Registration(transform, sitk.AffineTransform(3), grid).sampled()),
    ):
        began = time.perf_counter()
        moved = sitk.Resample(mask, patient, through(), sitk.sitkLabelLinear, 0, sitk.sitkUInt8)
        out[f"{name}_s"] = round(time.perf_counter() - began, 2)
        out[name] = sitk.GetArrayFromImage(moved) > 0
    exact, field = out.pop("exact"), out.pop("field")
    return {**out, "voxels_differing": int(np.count_nonzero(exact != field)), "brain_voxels": int(exact.sum())}


def cortex_points(run: Path, centre_mm: np.ndarray, count: int = 20, noise_mm: float = 0.5, seed: int = 3):
    """(pre, intra) mm RAS: fine-surface points within 25 mm of the craniotomy, and where the
    run's settled state moves them, plus noise."""
    import meshio

    surface = meshio.read(run / "surface_final.vtk")
    moved = surface.points * 1e3
    shift = surface.point_data["displacement"] * 1e3
    pre = moved - shift
    near = np.flatnonzero(np.linalg.norm(pre - centre_mm, axis=1) < 25.0)
    rng = np.random.default_rng(seed)
    picked = rng.choice(near, min(count, len(near)), replace=False)
    return pre[picked], moved[picked] + rng.normal(0.0, noise_mm, (len(picked), 3))


def one_case(name: str, data: Path, chain: bool, work: Path, ranks: int = 1) -> dict:
    path, extra, what, source = CASES[name]
    extra = [str(data / a) if a.startswith("t1gd_tumour/") else a for a in extra]
    if "SEG" in extra:  # the DICOM-SEG of VS-SEG-001 is not public beside its T1: no tumour then
        extra = extra[: extra.index("SEG") - 1] + extra[extra.index("SEG") + 1 :]
    folder = work / name
    log = work / f"{name}.log"
    earlier = RESULTS / f"{name}.json"
    before = json.loads(earlier.read_text()) if earlier.is_file() else {}
    if chain and (folder / "scene.toml").is_file() and before.get("prepare_args") == CASES[name][1]:
        return chain_steps(before, folder, log, ranks)  # prepared by an earlier call, as CASES says now: on from there
    log.unlink(missing_ok=True)
    from fenics_brainshift.bench import machine_line

    record = {"case": name, "what": what, "source": source, "machine": machine_line(), "prepare_args": CASES[name][1]}
    code, seconds = brainshift(["prepare", str(data / path), "-o", str(folder), *extra], log)
    prepared = json.loads((folder / "prepare.json").read_text()) if (folder / "prepare.json").is_file() else {}
    record.update(
        prepare_exit=code,
        prepare_s=round(seconds, 1),
        status=prepared.get("status", "ok" if code == 0 else "failed"),
        brain_litres=prepared.get("brain_litres"),
        correlation=prepared.get("correlation"),
        correlation_ratio=prepared.get("correlation_ratio"),
        correlation_ratio_moved=prepared.get("correlation_ratio_moved"),
        contrast=prepared.get("contrast"),
        registration=prepared.get("registration"),
        tumour=prepared.get("tumour"),
        craniotomy=prepared.get("craniotomy"),
    )
    if code != 0:
        return record
    record["gate_when_moved"] = gate_when_moved(folder)
    record["labels_carried"] = carried_both_ways(folder)
    return chain_steps(record, folder, log, ranks) if chain else record


CHAIN_KEYS = ("chain", "run_s", "update_s", "warp_s", "update", "update_fit_ms")
CHAIN_KEYS += ("error_near_craniotomy_mm", "operation_skull")
TRUTH_BELOW_RIM_M = 0.012  # the synthetic operation: drained this far below the scene's level,
TRUTH_SOFTER = 0.8  # with a brain this much softer than the scene's


def chain_steps(record: dict, folder: Path, log: Path, ranks: int = 1) -> dict:
    """The synthetic operation (the full model drained TRUTH_BELOW_RIM_M further, G times
    TRUTH_SOFTER: not the scene's own prediction), the default atlas (kept if an earlier call
    built it), an update from 20 pointer points of the operation's cortex near the craniotomy
    with 0.5 mm noise, the warp; and the update's error against the operation on the cortex
    within 25 mm of the craniotomy. The atlas on ``ranks`` MPI ranks (its modes shared among them)."""
    import tomllib

    for key in CHAIN_KEYS:  # (an earlier call's chain: not this one's)
        record.pop(key, None)
    prepared = json.loads((folder / "prepare.json").read_text())
    cut = prepared["craniotomy"]
    scene = tomllib.loads((folder / "scene.toml").read_text())
    truth_sets = [
        f"fluid.level=[[0.0, {cut['start_level_m']:.5f}], [10.0, {cut['rim_level_m'] - TRUTH_BELOW_RIM_M:.5f}]]",
        f"material.G={scene['material']['G'] * TRUTH_SOFTER:g}",
    ]
    steps = {}
    code, steps["run_s"] = brainshift(
        [
            "run",
            str(folder / "scene.toml"),
            "--out",
            str(folder / "operation"),
            *[a for t in truth_sets for a in ("--set", t)],
        ],
        log,
    )
    if code:
        return {**record, "chain": f"run exit {code}"}
    if (folder / "atlas" / "atlas.json").is_file() and record.get("atlas_s") and record.get("atlas_ranks", 1) == ranks:
        steps["atlas_s"] = record["atlas_s"]  # (built by an earlier call on as many ranks: its time kept)
    else:
        code, steps["atlas_s"] = brainshift(
            ["atlas", str(folder / "scene.toml"), "-o", str(folder / "atlas")], log, ranks
        )
        if code:
            return {**record, "chain": f"atlas exit {code}", **steps}
        record["atlas_ranks"] = ranks
    from fenics_brainshift.images.frames import write_markups

    centre = np.asarray(cut["centre_mm"])
    pre, intra = cortex_points(folder / "operation", centre)
    labels = [f"P{i + 1}" for i in range(len(pre))]
    write_markups(folder / "pre.mrk.json", labels, pre)
    write_markups(folder / "intra.mrk.json", labels, intra)
    code, steps["update_s"] = brainshift(
        [
            "update",
            str(folder / "atlas"),
            "--pre",
            str(folder / "pre.mrk.json"),
            "--target",
            str(folder / "intra.mrk.json"),
            "--noise",
            "0.5",
            "--out",
            str(folder / "update"),
            "--image",
            str(folder / "t1.nii.gz"),
            "--replace",
        ],
        log,
    )
    if code:
        return {**record, "chain": f"update exit {code}", **steps}
    update = json.loads((folder / "update" / "update.json").read_text())
    code, steps["warp_s"] = brainshift(
        ["warp", str(folder / "update"), "--image", str(folder / "t1.nii.gz"), "-o", str(folder / "t1_intra.nii.gz")],
        log,
    )
    record.update({k: round(v, 1) for k, v in steps.items()})
    record.update(
        chain="ok" if code == 0 else f"warp exit {code}",
        update={
            k: update[k]
            for k in ("prior_residual_rms_mm", "residual_rms_mm", "leave_one_out_rms_mm", "uncertainty_mm", "warning")
        },
        update_fit_ms=round(update["timings_ms"]["weights_ms"], 1),
        error_near_craniotomy_mm=near_craniotomy_error(folder, centre),
        operation_skull=operation_skull(folder),
    )
    return record


def operation_skull(folder: Path) -> dict:
    """What the synthetic operation's run says of the skull: the deepest node past it (mm)
    and the contact Newton solves counted settled though their residual was not at its target."""
    contact = json.loads((folder / "operation" / "summary.json").read_text())["skull_contact"]
    return {
        "deepest_past_mm": round(contact["max_penetration_m"] * 1e3, 4),
        "settled_without_descent": contact.get("settled_without_descent", 0),
        "settled_largest_step_um": round(contact.get("settled_largest_step_m", float("nan")) * 1e6, 2),
    }


def near_craniotomy_error(folder: Path, centre_mm: np.ndarray) -> dict:
    """RMS distance (mm) between the operation's cortex and the update's, and the atlas's prior
    (the scene's own prediction), over the fine surface within 25 mm of the craniotomy."""
    import meshio

    truth = meshio.read(folder / "operation" / "surface_final.vtk")
    updated = meshio.read(folder / "update" / "surface_final.vtk")
    from fenics_brainshift.atlas import store

    prior = store.read(folder / "atlas").prior_surface
    pre = (truth.points - truth.point_data["displacement"]) * 1e3
    near = np.linalg.norm(pre - centre_mm, axis=1) < 25.0
    rms = lambda d: round(float(np.sqrt(np.mean(np.sum(d[near] ** 2, axis=1)))) * 1e3, 3)  # noqa: E731
    true_u = np.asarray(truth.point_data["displacement"], dtype=float)
    return {
        "update": rms(np.asarray(updated.point_data["displacement"], dtype=float) - true_u),
        "scene": rms(prior - true_u),
        "points": int(near.sum()),
    }


def _update_cell(u: dict | None, r: dict) -> str:
    """The table's update cell: residual before -> after, and the fit's time."""
    if not u:
        return "-"
    return f"{u['prior_residual_rms_mm']:.2f} -> {u['residual_rms_mm']:.2f} mm, {r['update_fit_ms']:.0f} ms"


def _run_cell(r: dict) -> str:
    """The synthetic operation's seconds, or how it stopped (the chain ends there)."""
    if str(r.get("chain", "")).startswith("run exit"):
        return f"stopped ({r['chain']})"
    return str(r.get("run_s", "-"))


def _atlas_cell(r: dict) -> str:
    """The atlas's seconds, and on how many ranks it was built."""
    if r.get("atlas_s") is None:
        return "-"
    ranks = r.get("atlas_ranks", 1)
    return f"{r['atlas_s']} ({ranks} rank{'s' if ranks > 1 else ''})"


def report() -> None:

    rows = [json.loads(p.read_text()) for p in sorted(RESULTS.glob("*.json"))]
    machines = {}  # machine: the cases measured on it (each case's record says)
    for r in rows:
        machines.setdefault(r.get("machine", "not recorded"), []).append(r["case"])
    on = "; ".join(f"{m} ({', '.join(cases)})" for m, cases in machines.items())
    lines = [
        "# Real scans through `brainshift prepare` (and on)",
        "",
        f"Machines: {on}. Command: `OMP_NUM_THREADS=1 python benchmarks/prepare_cases.py --data DATA "
        f"--chain [--ranks 2]` then `--report` (one thread a process; the atlas on the ranks its cell "
        f"names, every other step one process).",
        "",
        "| case | contrast (said / measured) | result | brain l | template explains (moved 10 mm) | correlation "
        "| prepare s | run s | atlas s | update: residual, fit | warp s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        c = r.get("contrast") or {}
        u = r.get("update")
        lines.append(
            f"| {r['case']} | {c.get('given') or '-'} / {c.get('measured', '-')} | {r['status']} "
            f"| {r['brain_litres'] or '-'} | {100 * r['correlation_ratio']:.0f} % "
            f"({100 * (r.get('correlation_ratio_moved') or 0):.0f} %) | {r['correlation']} "
            f"| {r['prepare_s']} | {_run_cell(r)} | {_atlas_cell(r)} "
            f"| {_update_cell(u, r)} "
            f"| {r.get('warp_s', '-')} |"
            if r.get("correlation_ratio") is not None
            else f"| {r['case']} | - | {r['status']} (exit {r['prepare_exit']}) | - | - | - "
            f"| {r['prepare_s']} | | | | |"
        )
    lines += [
        "",
        "The synthetic operation (the cortex within 25 mm of the craniotomy: the scene's prediction and the "
        "update against it, RMS) and what its run says of the skull (the deepest node past it; contact "
        "Newton solves counted settled though their residual was not at its target):",
        "",
        "| case | head turned from supine | cortex near the craniotomy: scene / update | skull: deepest past, "
        "settled without descent |",
        "|---|---|---|---|",
    ]
    for r in rows:
        near, skull = r.get("error_near_craniotomy_mm"), r.get("operation_skull")
        if near and r.get("chain") == "ok":
            turned = (r.get("craniotomy") or {}).get("head_turned_from_supine_deg")
            turned = "-" if turned is None else f"{turned:.0f} degrees"
            past = "-"
            if skull:
                past = f"{skull['deepest_past_mm']:.3f} mm, {skull['settled_without_descent']}"
                if skull.get("settled_largest_step_um") is not None:
                    past += f" (largest step {skull['settled_largest_step_um']:g} um)"
            lines.append(
                f"| {r['case']} | {turned} | {near['scene']:.2f} / {near['update']:.2f} mm "
                f"({near['points']} points) | {past} |"
            )
    lines += [
        "",
        "The gate's measure (the share of the scan's variance in the deep brain found that the template "
        "explains, the correlation ratio) with each prepared registration moved on purpose (the patient point "
        "moved first; turned about the scan's centre):",
        "",
        "| case | found | moved 10 mm (x, y, z) | turned 10 degrees (x, y, z) |",
        "|---|---|---|---|",
    ]
    for r in rows:
        moved = r.get("gate_when_moved")
        if moved:
            ratios = [f"{100 * m['correlation_ratio']:.0f}" for m in moved]
            lines.append(f"| {r['case']} | {ratios[0]} % | {', '.join(ratios[1:4])} % | {', '.join(ratios[4:])} % |")
    lines += [
        "",
        "The labels carried through the registration at every voxel, and through its displacement "
        "field sampled on 2 mm (what prepare uses):",
        "",
        "| case | exact s | field s | voxels differing / brain voxels |",
        "|---|---|---|---|",
    ]
    for r in rows:
        c = r.get("labels_carried")
        if c:
            lines.append(
                f"| {r['case']} | {c['exact_s']} | {c['field_s']} | {c['voxels_differing']} / {c['brain_voxels']} |"
            )
    by_case = {r["case"]: r for r in rows}
    pairs = []
    for a, b in SAME_HEAD:
        va, vb = (by_case.get(n, {}).get("brain_litres") for n in (a, b))
        if va and vb:
            pairs.append(f"| {a} / {b} | {va:.3f} / {vb:.3f} | {100 * abs(va - vb) / max(va, vb):.1f} % |")
    if pairs:
        lines += ["", "The brain found on two contrasts of the same head:", ""]
        lines += ["| cases | brain l | difference |", "|---|---|---|", *pairs]
    lines += ["", "Cases: " + "; ".join(f"**{n}** {CASES[n][2]} ({CASES[n][3]})" for n in CASES) + "."]
    (RESULTS.parent / "prepare_cases.md").write_text("\n".join(lines) + "\n")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", help="the folder holding the scans as CASES names them")
    p.add_argument("--cases", default=",".join(CASES), help="comma-separated case names")
    p.add_argument("--chain", action="store_true", help="also run, atlas, update and warp")
    p.add_argument("--work", default="/tmp/prepare_cases", help="where the prepared folders go")
    p.add_argument("--ranks", type=int, default=1, help="the atlas under mpirun -n RANKS (its modes shared)")
    p.add_argument("--report", action="store_true", help="merge the results into prepare_cases.md")
    p.add_argument(
        "--regate",
        action="store_true",
        help="measure the gate with the registration moved again, and the contrast said, on the folders "
        "an earlier call prepared (their results files updated)",
    )
    args = p.parse_args(argv)
    if args.report:
        report()
        return 0
    if args.regate:
        from fenics_brainshift.patients.contrast import described_contrast
        from fenics_brainshift.patients.series import series_metadata

        for name in args.cases.split(","):
            path = RESULTS / f"{name}.json"
            record = json.loads(path.read_text())
            t1 = Path(args.data) / CASES[name][0]
            given, source = described_contrast(t1, series_metadata(t1))
            record["contrast"] = {**(record.get("contrast") or {}), "given": given, "from": source}
            if (Path(args.work) / name / "patient_to_template.h5").is_file():
                record["gate_when_moved"] = gate_when_moved(Path(args.work) / name)
            path.write_text(json.dumps(record, indent=2) + "\n")
        return 0
    RESULTS.mkdir(parents=True, exist_ok=True)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    for name in args.cases.split(","):
        record = one_case(name, Path(args.data), args.chain, work, args.ranks)
        (RESULTS / f"{name}.json").write_text(json.dumps(record, indent=2) + "\n")
        print(
            json.dumps(
                {
                    k: record.get(k)
                    for k in ("case", "status", "brain_litres", "correlation_ratio", "prepare_s", "chain")
                }
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
