# ---
# jupyter:
#   jupytext:
#     formats: py:light
# ---

# # The gelatin cube (Kato et al., section III)
#
# A 50 x 50 x 25 mm gelatin block (E = 729.1 Pa, nu = 0.48, 1048 kg/m3) is glued to the
# floor of a container of silicone oil (975 kg/m3). As the oil drains, buoyancy falls and the
# block sags under its own weight. The scene is `cube.toml` beside this file; this script
# runs it (serially or under `mpirun -n N`) and reports the top-centre displacement.
#
#     python demos/cube.py                      # serial, writes out_cube/
#     mpirun -n 2 python demos/cube.py          # the same answer on two ranks

# +
import argparse
import sys
from pathlib import Path

from mpi4py import MPI

from fenics_brainshift import logs
from fenics_brainshift.scene import SceneError, load_scene
from fenics_brainshift.simulation import run

HERE = Path(__file__).resolve().parent
# -


def parse_args(argv=None):
    p = argparse.ArgumentParser(description="The paper's gelatin cube: sag as the oil drains.", formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--scene", default=str(HERE / "cube.toml"), help="scene file")
    p.add_argument("--out", default="out_cube", help="output folder")
    p.add_argument("--end", type=float, help="end time in s (default: the scene's)")
    p.add_argument("--degree", type=int, choices=(1, 2), help="element degree (default: the scene's)")
    p.add_argument("--solver", choices=("cg-gamg", "cg-jacobi", "cholesky", "lu"), help="linear solver")
    p.add_argument("--cells", type=int, nargs=3, metavar=("NX", "NY", "NZ"), help="hexahedra per side")
    return p.parse_args(argv)


# ## Load the scene, apply the command-line overrides, run, report

# +
def main(argv=None) -> int:
    args = parse_args(argv)
    logs.configure("INFO")
    comm = MPI.COMM_WORLD
    try:
        scene = load_scene(args.scene)
        if args.end is not None:
            scene.time.end = args.end
        if args.degree is not None:
            scene.element.degree = args.degree
            scene.element.mass = "lumped" if args.degree == 1 else "consistent"
        if args.solver is not None:
            scene.solver.kind = args.solver
        if args.cells is not None:
            scene.mesh.cells = tuple(args.cells)
        summary = run(scene, args.out, comm)
    except SceneError as exc:
        if comm.rank == 0:
            print(f"cube.py: error: {exc}", file=sys.stderr)
        return 2

    # What came out: the top-centre probe sinks as the oil drains; the resultant fluid
    # force is rho_oil g (submerged volume), the weight rho_gel g V.
    if comm.rank == 0:
        top = summary["probes"]["top_centre"]
        print(f"gelatin cube: {summary['nodes']} nodes, {summary['cells']} tetrahedra, P{summary['degree']}, "
              f"{summary['ranks']} rank(s)")
        print(f"  oil level {summary['final_level_m'] * 1e3:.1f} mm at t = {summary['final_time']:.2f} s: "
              f"top-centre displacement {top[2] * 1e3:.3f} mm")
        print(f"  weight {summary['gravity_force_N'][2]:.4f} N, buoyancy {summary['fluid_force_N'][2]:.4f} N")
        print(f"  setup {summary['setup_s']:.2f} s, {summary['steps']} steps, "
              f"median {summary['step_s_median'] * 1e3:.1f} ms per step; results in {args.out}/")
    return 0
# -


if __name__ == "__main__":
    sys.exit(main())
