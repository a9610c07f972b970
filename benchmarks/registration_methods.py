"""Template-to-patient registration: the project's SimpleITK method against ANTs (antspyx), on
real head scans and on a synthetic head with a known truth: success, brain accuracy and time
on real cases, to keep what wins and say why (docs/patients.md).

Methods (both register the template, moving, to the patient, fixed, on one thread):

* ``sitk``: patients/registration.py's ``register(patient, ICBM152 T1, head=FSL MNI152 head,
  brain=ICBM152 brain mask)``, as `brainshift prepare` runs it (head rigid + affine, brain
  affine, B-spline; Mattes MI); the brain mask carried by carry.py's ``labels_on_patient``.
* ``ants``: ``ants.registration(fixed=patient, moving=template_head, type_of_transform=ANTS_TYPE)``
  with ANTS_TYPE = 'antsRegistrationSyNQuick[s]' (rigid + affine + SyN, all Mattes MI, shrink
  8x4x2x1 with no iterations at 1: every stage ends at twice the patient grid's spacing), the
  ANTs authors' quick setting. ``template_head`` is
  the ICBM152 T1 inside FSL's MNI152 head on the ICBM152 1 mm grid (synthetic.py's
  ``with_head``), so the ICBM152 brain mask carried is the brain of the image registered. The
  patient is given as the project gives it to its own registration, ``normalised(coarsened(T1))``
  (intensities windowed to the 1st-99th percentile), but coarsened to ANTS_SPACING = 2 mm, not 1 mm
  (--ants-spacing): on 1 mm the quick SyN took 427 s on one thread for vs001 and 291 s for t2w,
  past the ~6 minute budget; the template ``normalised`` (1 mm).
  The brain mask is carried with the forward transforms onto the patient's own grid
  (``genericLabel`` interpolation); ANTs' random sampling seeded (``--random-seed 1``).

Both brains then go through prepare's own clean-up (the largest face-connected part, holes
filled), and are judged by prepare's gate, the same function on each method's transform
(fit_measures.py ``fit_measures``; for ANTs its forward composite transform, written as ITK
HDF5, read by SimpleITK: patient LPS mm -> template LPS mm): success = brain 1.0-1.7 l and
ratio >= 0.1 and ratio - ratio_moved >= 0.05. Per case: brain volume, Dice of the two methods'
brains, wall time of the registration (one process, one thread: ITK_GLOBAL_DEFAULT_NUMBER_OF_THREADS=1,
OMP_NUM_THREADS=1; the two methods alternate which goes first from case to case). On the
synthetic patient (benchmarks/prepare.py's: with_head's T1 turned, scaled 0.9, warped 3 mm,
bias, noise, 256 x 256 x 176 at 1 mm, oblique), also Dice and volume error against the brain
mask carried by its known transform.

antspyx is not a dependency of the project: install it separately, into a venv that sees the
system's dolfinx/petsc4py (numpy pinned to the system's so petsc4py still imports), and run
with the project on PYTHONPATH (not installed into that venv):

    /usr/bin/python3 -m venv --system-site-packages /tmp/antsvenv
    echo numpy==1.24.2 > /tmp/c.txt
    /tmp/antsvenv/bin/pip install -c /tmp/c.txt antspyx SimpleITK==2.5.7
    cd /work/main && ITK_GLOBAL_DEFAULT_NUMBER_OF_THREADS=1 OMP_NUM_THREADS=1 ANTS_RANDOM_SEED=1 \\
        PYTHONPATH=/work/main /tmp/antsvenv/bin/python benchmarks/registration_methods.py \\
        [--cases a,b] [--data /work/data]

Each finished case is kept in --store (default /tmp/registration_methods.json) as it ends (a later
run with --cases adds to it); benchmarks/results/registration_methods.md is rewritten from it
after every case.
"""

from __future__ import annotations

import os

os.environ.setdefault("ITK_GLOBAL_DEFAULT_NUMBER_OF_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("ANTS_RANDOM_SEED", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import SimpleITK as sitk  # noqa: E402
from scipy import ndimage  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.data.templates import largest_part, mni_brain_mask, mni_head, mni_t1  # noqa: E402
from fenics_brainshift.patients.carry import labels_on_patient  # noqa: E402
from fenics_brainshift.patients.fit_measures import fit_measures  # noqa: E402
from fenics_brainshift.patients.gate import MIN_PEAK, MIN_RATIO, PLAUSIBLE  # noqa: E402
from fenics_brainshift.patients.registration import coarsened, normalised, register, shows_head  # noqa: E402
from fenics_brainshift.patients.series import read_t1  # noqa: E402
from fenics_brainshift.patients.synthetic import synthetic_patient, with_head  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
ANTS_TYPE = "antsRegistrationSyNQuick[s]"
# mm: the patient's grid ANTs registers on. At 1 mm (as the sitk method) the quick SyN took
# 427 s on one thread for vs001 and 291 s for t2w, past the ~6 minute budget per case: 2 mm
ANTS_SPACING = 2.0
SEED = int(os.environ["ANTS_RANDOM_SEED"])
CASES = {  # name: (path under --data, what)
    "vs001": ("t1gd_tumour/VS-SEG-001_ceT1_dicom", "post-contrast 3D T1, 0.41 x 0.41 x 1.5 mm, DICOM, fiducials"),
    "chris_t1": ("t1_native/chris_t1.nii.gz", "native 3D T1, 0.88 mm (the head of chris_pd)"),
    "chris_pd": ("t2_flair_pd/chris_PD.nii.gz", "PD, 0.86 x 0.86 x 2.4 mm, vertex to skull base"),
    "t2w": ("t2_flair_pd/niivue_register_T2w.nii.gz", "2-D T2 TSE, 1 x 1 x 2 mm, vertex to skull base"),
    "trio_t1": ("t1_native/trio_b17_t1_MPRAGEcr_noGRAPPA_19_dicom", "native MPRAGE, 1 mm, sagittal, DICOM"),
    "synthetic": (None, "ICBM152 in FSL's head, moved by a known map, 256 x 256 x 176 at 1 mm (truth known)"),
}


class Carried:
    """What fit_measures reads of a Registration: its patient -> template transform."""

    def __init__(self, transform: sitk.Transform):
        self.transform = transform


def templates() -> dict:
    t1 = sitk.ReadImage(str(mni_t1()), sitk.sitkFloat32)
    brain = sitk.ReadImage(str(mni_brain_mask()))
    head = sitk.ReadImage(str(mni_head()), sitk.sitkFloat32)
    head_brain = sitk.ReadImage(str(mni_head(brain_mask=True)))
    return {
        "t1": t1,
        "brain": brain,
        "brain_array": sitk.GetArrayFromImage(brain) > 0,
        "head": head,
        "t1_head": with_head(t1, head, head_brain, brain),
    }


def cleaned(labels: np.ndarray) -> np.ndarray:
    """prepare's clean-up of the carried brain (patients/prepare.py): largest part, holes filled."""
    return ndimage.binary_fill_holes(largest_part(labels > 0))


def run_sitk(patient: sitk.Image, tpl: dict) -> dict:
    head = tpl["head"] if shows_head(patient) else None
    began = time.perf_counter()
    registration = register(patient, tpl["t1"], deformable=True, head=head, brain=tpl["brain"])
    seconds = time.perf_counter() - began
    began = time.perf_counter()
    brain = cleaned(labels_on_patient({1: tpl["brain_array"]}, tpl["brain"], patient, registration))
    carry = time.perf_counter() - began
    return {
        "brain": brain,
        "transform": registration.transform,
        "seconds": seconds,
        "carry_seconds": carry,
        "head_first": head is not None,
        "stages": [
            f"{s['stage']} {s['seconds']:.0f} s{'' if s['accepted'] else ' (rejected)'}" for s in registration.stages
        ],
    }


def run_ants(patient: sitk.Image, tpl: dict, tmp: Path) -> dict:
    import ants

    ants.config._random_seed = SEED  # passed as antsRegistration's --random-seed
    began = time.perf_counter()
    fixed = ants.from_sitk(normalised(coarsened(patient, ANTS_SPACING)))
    moving = ants.from_sitk(normalised(tpl["t1_head"]))
    out = ants.registration(
        fixed=fixed,
        moving=moving,
        type_of_transform=ANTS_TYPE,
        outprefix=str(tmp / "ants_"),
        write_composite_transform=True,
    )
    seconds = time.perf_counter() - began
    began = time.perf_counter()
    mask = ants.from_sitk(sitk.Cast(tpl["brain"], sitk.sitkFloat32))
    carried = ants.apply_transforms(
        fixed=ants.from_sitk(patient), moving=mask, transformlist=out["fwdtransforms"], interpolator="genericLabel"
    )
    labels = sitk.GetArrayFromImage(ants.to_sitk(carried))
    carry = time.perf_counter() - began
    # the forward composite (patient point -> template point), as SimpleITK reads it
    transform = sitk.ReadTransform(str(out["fwdtransforms"]))
    return {
        "brain": cleaned(labels > 0.5),
        "transform": transform,
        "seconds": seconds,
        "carry_seconds": carry,
        "check": transform_check(tpl, patient, transform, out["fwdtransforms"]),
    }


def transform_check(tpl, patient, transform, fwd) -> dict:
    """The template resampled onto the (1 mm) patient by SimpleITK through the transform read, and
    by antspyx through its own files: they must agree for fit_measures to judge ANTs' result."""
    import ants

    grid = coarsened(patient)[::2, ::2, ::2]
    by_sitk = sitk.GetArrayFromImage(sitk.Resample(tpl["t1"], grid, transform, sitk.sitkLinear, 0.0))
    by_ants = ants.apply_transforms(fixed=ants.from_sitk(grid), moving=ants.from_sitk(tpl["t1"]), transformlist=fwd)
    by_ants = sitk.GetArrayFromImage(ants.to_sitk(by_ants))
    scale = float(np.percentile(by_sitk[by_sitk > 0], 99)) if np.any(by_sitk > 0) else 1.0
    return {
        "mean_abs_diff_rel": round(float(np.abs(by_sitk - by_ants).mean()) / scale, 5),
        "correlation": round(float(np.corrcoef(by_sitk.ravel(), by_ants.ravel())[0, 1]), 5),
    }


def judged(patient: sitk.Image, tpl: dict, run: dict) -> dict:
    voxel_l = float(np.prod(patient.GetSpacing())) * 1e-6
    litres = float(run["brain"].sum()) * voxel_l
    m = fit_measures(patient, tpl["t1"], Carried(run["transform"]), run["brain"])
    plausible = PLAUSIBLE[0] <= litres <= PLAUSIBLE[1]
    gate = m["ratio"] >= MIN_RATIO and m["ratio"] - m["ratio_moved"] >= MIN_PEAK
    return {
        "litres": round(litres, 4),
        "correlation": round(m["correlation"], 4),
        "ratio": round(m["ratio"], 4),
        "ratio_moved": round(m["ratio_moved"], 4),
        "peak": round(m["ratio"] - m["ratio_moved"], 4),
        "plausible": plausible,
        "gate": gate,
        "success": plausible and gate,
        "seconds": round(run["seconds"], 1),
        "carry_seconds": round(run["carry_seconds"], 1),
    }


def dice(a: np.ndarray, b: np.ndarray) -> float:
    return float(2 * (a & b).sum() / max(a.sum() + b.sum(), 1))


def one_case(name: str, data: Path, tpl: dict, order: list[str]) -> dict:
    path, what = CASES[name]
    truth = None
    if path is None:
        synthetic = synthetic_patient(tpl["t1_head"], spacing=(1.0, 1.0, 1.0), size=(256, 256, 176))
        patient = synthetic.image
        mask = sitk.Cast(tpl["brain"], sitk.sitkFloat32)
        truth = sitk.GetArrayFromImage(sitk.Resample(mask, patient, synthetic.known, sitk.sitkLinear, 0.0)) >= 0.5
    else:
        patient = read_t1(data / path)
    record = {
        "case": name,
        "what": what,
        "size": list(patient.GetSize()),
        "spacing_mm": [round(s, 4) for s in patient.GetSpacing()],
        "order": order,
        "methods": {},
    }
    runs = {}
    with tempfile.TemporaryDirectory() as tmp:
        for method in order:
            print(f"[{name}] {method} ...", flush=True)
            runs[method] = run_sitk(patient, tpl) if method == "sitk" else run_ants(patient, tpl, Path(tmp))
            record["methods"][method] = judged(patient, tpl, runs[method])
            for key in ("stages", "head_first", "check"):
                if key in runs[method]:
                    record["methods"][method][key] = runs[method][key]
            print(f"[{name}] {method}: {record['methods'][method]}", flush=True)
    record["dice_between"] = round(dice(runs["sitk"]["brain"], runs["ants"]["brain"]), 4)
    if truth is not None:
        voxel_l = float(np.prod(patient.GetSpacing())) * 1e-6
        record["truth_litres"] = round(float(truth.sum()) * voxel_l, 4)
        for method, run in runs.items():
            found = run["brain"]
            record["methods"][method]["dice_truth"] = round(dice(found, truth), 4)
            record["methods"][method]["volume_error"] = round(float(found.sum()) / float(truth.sum()) - 1.0, 4)
    return record


def write_markdown(records: dict, command: str, machine: str) -> str:
    yes = {True: "yes", False: "**no**"}
    lines = [
        "# Template-to-patient registration: the project's SimpleITK method against ANTs (antspyx)",
        "",
        f"Machine: {machine}. One process, one thread (ITK_GLOBAL_DEFAULT_NUMBER_OF_THREADS=1, OMP_NUM_THREADS=1); "
        f"another job shared the 2 cores throughout, so the seconds carry its noise (the methods alternate which "
        f"goes first from case to case).",
        "",
        f"Command: `{command}`",
        "",
        f"Methods (benchmarks/registration_methods.py's docstring): **sitk** = `register()` as `brainshift prepare` "
        f"runs it (FSL head rigid + affine, ICBM152 brain affine, B-spline; Mattes MI); **ants** = "
        f"`ants.registration(type_of_transform='{ANTS_TYPE}')` on the patient resampled to "
        f"{ANTS_SPACING:g} mm (1 mm took 427 s for vs001), of the ICBM152 T1 inside FSL's head "
        f"(synthetic.py `with_head`) to the patient, the ICBM152 brain mask carried with `genericLabel`. "
        f"Both brains: prepare's clean-up (largest part, holes filled) and prepare's gate by `fit_measures` on each "
        f"method's own transform. Success = brain {PLAUSIBLE[0]}-{PLAUSIBLE[1]} l, ratio >= {MIN_RATIO} and "
        f"ratio - ratio_moved >= {MIN_PEAK}. Seconds: the registration alone (the mask's carrying in brackets).",
        "",
        "| Case | Method | Success | Brain (l) | Ratio | Peak (ratio - moved) | Correlation | Dice sitk vs ants "
        "| Dice vs truth | Volume error | Registration s (carry s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in CASES:
        if name not in records:
            continue
        r = records[name]
        for method in ("sitk", "ants"):
            m = r["methods"][method]
            truth = f"{m['dice_truth']:.3f} | {m['volume_error']:+.1%}" if "dice_truth" in m else "- | -"
            lines.append(
                f"| {name} | {method} | {yes[m['success']]} | {m['litres']:.3f} | {m['ratio']:.3f} "
                f"| {m['peak']:+.3f} | {m['correlation']:+.3f} | {r['dice_between']:.3f} | {truth} "
                f"| {m['seconds']:.0f} ({m['carry_seconds']:.0f}) |"
            )
    lines.append("")
    if "synthetic" in records:
        lines.append(f"Synthetic truth: {records['synthetic']['truth_litres']:.3f} l.")
    if "chris_t1" in records and "chris_pd" in records:
        parts = []
        for method in ("sitk", "ants"):
            a, b = records["chris_t1"]["methods"][method]["litres"], records["chris_pd"]["methods"][method]["litres"]
            parts.append(f"{method} {a:.3f} l (T1) against {b:.3f} l (PD), {b / a - 1:+.1%}")
        lines.append(
            "Same head, two scans (chris_t1 / chris_pd): " + "; ".join(parts) + ". The PD covers vertex to "
            "skull base only (130 mm), so part of the difference is the field of view."
        )
    checks = [
        f"{n} {records[n]['methods']['ants']['check']['correlation']:.4f}"
        for n in CASES
        if n in records and "check" in records[n]["methods"]["ants"]
    ]
    if checks:
        lines.append("")
        lines.append(
            "ANTs' forward composite read by SimpleITK (used for the gate) against antspyx's own "
            "apply_transforms, correlation of the template resampled both ways: " + ", ".join(checks) + "."
        )
    missing = [n for n in CASES if n not in records]
    if missing:
        lines.append("")
        lines.append("Not run: " + ", ".join(missing) + ".")
    totals = {m: sum(records[n]["methods"][m]["seconds"] for n in records) for m in ("sitk", "ants")}
    wins = {m: sum(records[n]["methods"][m]["success"] for n in records) for m in ("sitk", "ants")}
    lines += [
        "",
        f"Successes: sitk {wins['sitk']}/{len(records)}, ants {wins['ants']}/{len(records)}; registration "
        f"seconds summed: sitk {totals['sitk']:.0f}, ants {totals['ants']:.0f}.",
        "",
    ]
    return "\n".join(lines)


def main(argv=None) -> int:
    global ANTS_SPACING
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--cases", default=",".join(CASES), help="comma-separated, of " + ", ".join(CASES))
    p.add_argument("--data", default="/work/data")
    p.add_argument(
        "--ants-spacing",
        type=float,
        default=ANTS_SPACING,
        help="mm: the patient's grid ANTs registers on (default %(default)s)",
    )
    p.add_argument(
        "--store",
        default="/tmp/registration_methods.json",
        help="the finished cases, kept as each ends (a later run adds to it)",
    )
    p.add_argument("--fresh", action="store_true", help="forget the cases kept from earlier runs")
    args = p.parse_args(argv)
    sitk.ProcessObject.SetGlobalDefaultNumberOfThreads(1)
    ANTS_SPACING = args.ants_spacing
    names = [n.strip() for n in args.cases.split(",") if n.strip()]
    unknown = [n for n in names if n not in CASES]
    if unknown:
        raise SystemExit(f"unknown case(s) {unknown}; known: {list(CASES)}")
    store = Path(args.store)
    kept = {} if args.fresh or not store.is_file() else json.loads(store.read_text())
    records = kept.get("cases", {})
    command = (
        "ITK_GLOBAL_DEFAULT_NUMBER_OF_THREADS=1 OMP_NUM_THREADS=1 ANTS_RANDOM_SEED=1 PYTHONPATH=/work/main "
        "/tmp/antsvenv/bin/python benchmarks/registration_methods.py"
        + ("" if names == list(CASES) else f" --cases {','.join(names)}")
        + ("" if ANTS_SPACING == 2.0 else f" --ants-spacing {ANTS_SPACING:g}")
    )
    machine = machine_line()
    tpl = templates()
    for i, name in enumerate(names):
        order = ["sitk", "ants"] if i % 2 == 0 else ["ants", "sitk"]
        records[name] = one_case(name, Path(args.data), tpl, order)
        records = {n: records[n] for n in CASES if n in records}
        records[name]["ants_spacing_mm"] = ANTS_SPACING
        store.write_text(json.dumps({"machine": machine, "ants_type": ANTS_TYPE, "cases": records}, indent=1) + "\n")
        (RESULTS / "registration_methods.md").write_text(write_markdown(records, command, machine))
    print(write_markdown(records, command, machine))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
