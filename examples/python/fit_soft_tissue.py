"""Workflow 4: fit the body shape β and the soft tissue's material to 4D scans (issue 25).

Ground truth made by the simulator: a body of hidden shape (β₀, β₁) whose soft tissue is twice as
stiff along the fibre (E1) as the default and has a 1.5× Fung exponent jumps on the ground (FEM
or ROM soft skeleton). Its simulated surface at 30 Hz plus 2 mm noise is the scan, given either
as the vertices in SMPL order (--loss vertices: known correspondences) or as points drawn
uniformly over the surface in random order (--loss surface: each point against the nearest
point of the simulated surface, flsh.torch.point_to_surface). From β = 0 and the default
material, L-BFGS on the adjoint gradients of flsh.torch.simulate finds them.

--subjects N fits one material shared by N bodies of known, different shapes (β₀ from −1 to 1),
the way the FLSH paper estimated its soft-tissue parameters from the DYNA scans.

--basis picks the ROM's reduced basis: "handles" (this example's default, that of its figures in
docs/adjoint.md: bounded biharmonic weights of surface handles), "modes" (the library's default:
static-correction modes of every bone DoF plus --vibration-modes fixed-interface modes,
compressed to --modal-columns) or "modes+handles".

Printed: the parameters (truth, start, fit), the surface's RMS distance to the noise-free truth
before and after, loss evaluations, L-BFGS iterations and wall time.

Usage:
    PYTHONPATH=build/python /usr/bin/python3 examples/python/fit_soft_tissue.py \\
        [--model fem|rom] [--basis handles|modes|modes+handles] [--vibration-modes 24] \\
        [--modal-columns 72] [--vertices 0] [--steps 24] [--loss vertices|surface] \\
        [--subjects 1] [--iterations 30] [--cache DIR]
--vertices 0 is the full-size synthetic body (6890 vertices); small bodies run in seconds.
"""
import argparse
import time

import numpy as np
import torch

import flsh
import flsh.torch
from flsh.fitting import minimize

NOISE = 0.002  # m
FPS = 30.0
MATERIAL_KEYS = ("layers.soft_tissue.E1", "layers.soft_tissue.fung_gamma")
TRUE_MATERIAL = (np.log(2.0), np.log(1.5))  # log-factors of E1 and the Fung exponent
TRUE_BETAS = (0.8, -0.6)  # β₀, β₁ (the others stay 0)
SMALL_ROM = dict(handles=16, elastic_cubature_points=60, inertial_cubature_points=60,
                 cubature_training_samples=80)


class Problem:
    """The simulator of the jump and the maps from the unknowns to simulated surfaces."""

    def __init__(self, body, shapes, model="rom", steps=24, cache=None, basis=None):
        self.body = body
        self.faces = torch.tensor(np.asarray(body.faces), dtype=torch.long)
        jump = flsh.make_builtin_motion("jump", seconds=max(1.6, (steps + 2) / FPS), fps=FPS)
        # The ground where the lowest sole of the subjects (shapes: their first β components)
        # stands before the take-off: the scene's, known.
        floor = np.inf
        for first in shapes:
            betas = torch.zeros(body.num_betas, dtype=torch.float64)
            betas[:len(first)] = first
            v, _ = flsh.torch.smpl(body, betas, torch.tensor(jump.poses[0]),
                                   torch.tensor(jump.trans[0]))
            floor = min(floor, float(v[:, 1].min()))
        ground = flsh.Collider.plane(point=[0.0, floor, 0.0], normal=[0.0, 1.0, 0.0])
        small = body.num_vertices < 6890
        settings = dict(SMALL_ROM) if (small and model == "rom") else {}
        if model == "rom":
            settings.update(basis or {"basis": "handles"})
            if settings["basis"] == "modes":  # the modal basis alone has no handles
                settings.pop("handles", None)
        kwargs = dict(steps=steps, model=model, cache_dir=cache, colliders=[ground],
                      avatar_settings=settings)
        if small:
            kwargs.update(voxel_size=0.02, resolution=0.5)
        self.simulator = flsh.torch.RolloutSimulator(body, jump, **kwargs)
        names = self.simulator.material_names()
        self.index = torch.tensor([names.index(f"{k}.log_value") for k in MATERIAL_KEYS])
        self.own = torch.tensor(self.simulator.own_material())

    def material(self, log_factors):
        """The avatar's own material with log_factors added to the log-values of MATERIAL_KEYS."""
        return self.own.index_put((self.index,), self.own[self.index] + log_factors)

    def betas(self, first):
        betas = torch.zeros(self.simulator.num_betas, dtype=torch.float64)
        return betas.index_put((torch.arange(len(first)),), first)

    def surface(self, betas, log_factors):
        """(T, V, 3) simulated surface vertices."""
        _, vertices = flsh.torch.simulate(self.simulator, betas=betas,
                                          material=self.material(log_factors), vertices=True)
        return vertices


def scan_points(vertices, faces, generator):
    """Per frame, V points drawn uniformly over the surface (area-weighted faces, uniform
    barycentric coordinates) in random order: (T, V, 3)."""
    frames = []
    for x in vertices:
        tri = x[faces]
        area = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).norm(dim=-1)
        f = torch.multinomial(area, x.shape[0], replacement=True, generator=generator)
        r = torch.rand(x.shape[0], 2, generator=generator, dtype=torch.float64)
        s = r[:, 0].sqrt()
        w = torch.stack([1 - s, s * (1 - r[:, 1]), s * r[:, 1]], -1)
        frames.append((w[:, :, None] * tri[f]).sum(-2))
    return torch.stack(frames)


def fit(vertices=800, model="rom", steps=24, loss="vertices", subjects=1, iterations=30,
        seed=7, cache=None, log=print, basis=None):
    """Runs the workflow and returns its figures (a dict). basis: the ROM's basis settings
    (avatar settings such as dict(basis="modes", vibration_modes=24, modal_columns=72)); None:
    the handle basis (16 handles on small bodies, 87 at full size)."""
    started = time.perf_counter()
    body = flsh.make_synthetic_body(vertices=vertices) if vertices else \
        flsh.make_synthetic_body()
    true_material = torch.tensor(TRUE_MATERIAL, dtype=torch.float64)
    if subjects == 1:
        shapes = [torch.tensor(TRUE_BETAS, dtype=torch.float64)]  # unknown: fitted
    else:
        shapes = [torch.tensor([b0, 0.0], dtype=torch.float64)
                  for b0 in np.linspace(-1.0, 1.0, subjects)]  # known
    problem = Problem(body, shapes, model, steps, cache, basis)
    generator = torch.Generator().manual_seed(seed)
    fit_shape = subjects == 1
    clean, scans = [], []
    with torch.no_grad():
        for shape in shapes:
            v = problem.surface(problem.betas(shape), true_material)
            clean.append(v)
            if loss == "surface":
                points = scan_points(v, problem.faces, generator)
            else:
                points = v
            scans.append(points + NOISE * torch.randn(points.shape, generator=generator,
                                                      dtype=torch.float64))
    basis_text = "" if model != "rom" or not basis else \
        f" ({basis['basis']}: {basis.get('vibration_modes')} vibration modes, " \
        f"{basis.get('modal_columns')} columns)"
    log(f"{model.upper()}{basis_text}, {body.num_vertices} vertices, {steps} steps of the jump at "
        f"{FPS:.0f} Hz on the ground, {subjects} subject(s), loss on "
        f"{'unordered scan points' if loss == 'surface' else 'vertices'}, "
        f"truth simulated in {time.perf_counter() - started:.1f} s")

    def unpack(x):
        if fit_shape:
            return [x[:2]], x[2:]
        return shapes, x

    evaluations = 0

    def objective(x):
        nonlocal evaluations
        evaluations += 1
        betas_list, log_factors = unpack(x)
        total = 0.0
        for betas, scan in zip(betas_list, scans):
            v = problem.surface(problem.betas(betas), log_factors)
            if loss == "surface":
                d2 = flsh.torch.point_to_surface(scan, v, problem.faces)
                total = total + d2.mean() / NOISE ** 2
            else:
                total = total + ((v - scan) ** 2).sum(-1).mean() / NOISE ** 2
        return total / len(scans)

    def surface_error(x):
        with torch.no_grad():
            betas_list, log_factors = unpack(x)
            errors = [((problem.surface(problem.betas(b), log_factors) - c) ** 2).sum(-1)
                      for b, c in zip(betas_list, clean)]
            return float(torch.cat([e.reshape(-1) for e in errors]).mean().sqrt())

    size = 4 if fit_shape else 2
    x0 = torch.zeros(size, dtype=torch.float64)
    truth = torch.cat([shapes[0], true_material]) if fit_shape else true_material
    with torch.no_grad():
        start_loss, truth_loss = float(objective(x0)), float(objective(truth))
    fit_started = time.perf_counter()
    x, lbfgs_iterations = minimize(objective, x0, iterations)
    fit_seconds = time.perf_counter() - fit_started
    with torch.no_grad():
        final_loss = float(objective(x))
    names = (["β₀", "β₁"] if fit_shape else []) + ["log E1 factor", "log γ factor"]
    log(f"{'parameter':>14} {'truth':>9} {'start':>9} {'fit':>9} {'error':>9}")
    for k, name in enumerate(names):
        log(f"{name:>14} {float(truth[k]):9.4f} {float(x0[k]):9.4f} {float(x[k]):9.4f} "
            f"{float(x[k] - truth[k]):9.4f}")
    before, after = surface_error(x0), surface_error(x)
    log(f"surface RMS distance to the noise-free truth: {1e3 * before:.3f} mm → "
        f"{1e3 * after:.3f} mm")
    log(f"loss (mean squared distance / noise²): start {start_loss:.4f}, fit {final_loss:.4f}, "
        f"truth {truth_loss:.4f}")
    log(f"L-BFGS: {lbfgs_iterations} iterations, {evaluations} loss evaluations "
        f"(simulation + gradient), {fit_seconds:.1f} s")
    return dict(truth=truth.numpy(), start=x0.numpy(), estimate=x.numpy(), names=names,
                surface_error_before=before, surface_error_after=after, start_loss=start_loss,
                final_loss=final_loss, truth_loss=truth_loss, iterations=lbfgs_iterations,
                evaluations=evaluations, seconds=fit_seconds)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", choices=("fem", "rom"), default="rom")
    parser.add_argument("--vertices", type=int, default=0,
                        help="synthetic body size (0: full size, 6890)")
    parser.add_argument("--steps", type=int, default=24)
    parser.add_argument("--loss", choices=("vertices", "surface"), default="vertices")
    parser.add_argument("--subjects", type=int, default=1)
    parser.add_argument("--iterations", type=int, default=30)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--cache", default=None, help="avatar cache folder")
    parser.add_argument("--basis", choices=("handles", "modes", "modes+handles"),
                        default="handles", help="the ROM's reduced basis")
    parser.add_argument("--vibration-modes", type=int, default=24,
                        help="fixed-interface vibration modes (--basis modes…)")
    parser.add_argument("--modal-columns", type=int, default=72,
                        help="columns after compression (--basis modes…; 0 keeps them all)")
    args = parser.parse_args()
    if args.steps < 1 or args.subjects < 1 or args.iterations < 1:
        parser.error("--steps, --subjects and --iterations must be ≥ 1")
    if args.vibration_modes < 0 or args.modal_columns < 0:
        parser.error("--vibration-modes and --modal-columns must be ≥ 0")
    basis = None
    if args.basis != "handles":
        basis = dict(basis=args.basis, vibration_modes=args.vibration_modes,
                     modal_columns=args.modal_columns)
    fit(args.vertices, args.model, args.steps, args.loss, args.subjects, args.iterations,
        args.seed, args.cache, basis=basis)


if __name__ == "__main__":
    main()
