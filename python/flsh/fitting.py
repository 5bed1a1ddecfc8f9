"""Fitting a simulation to 4D scans: the body shape β and soft-tissue material coefficients that
make a simulated motion match scanned surfaces (docs/adjoint.md, "Fitting to scans"), by L-BFGS
on the adjoint gradients of flsh.torch.simulate.

    sim = flsh.torch.RolloutSimulator.from_scene("subject.json")   # body, motion, model, ground
    scans = flsh.fitting.load_scans("subject_scans.npz", sim)
    result = flsh.fitting.fit_scans(sim, scans, betas=2, material=["layers.soft_tissue.E1"])
    result.save_material("fitted_material.json")                    # a scene's "materials"

A scan file is an .npz with one of
    vertices  (F, V, 3)  the scanned surface in the body model's vertex order (registered scans:
                         known correspondences), m
    points    (F, N, 3)  points on the scanned surface in any order (raw scans), m
and optionally
    times     (F,)       s; each a step time k·h of the simulation (k = 1..T; frames at t = 0 are
                         the start state, which the fit does not change, and are skipped);
                         without it the frames are steps 1..F.
flsh.batch's data.npz (its "vertices" and "times") is a scan file.

The loss is the mean squared distance between the scans and the simulated surface over the
scanned frames (vertex to vertex, or each point to its closest point of the surface) divided by
noise² (the scans' noise level: it only scales the loss).
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from . import torch as flsh_torch

__all__ = ["FitResult", "Scans", "fit_scans", "load_scans", "material_entries", "minimize"]

SCAN_KINDS = ("vertices", "points")
MAX_COORDINATE = 1e4  # m: the state bound of the simulation (kMaxStatePosition)


@dataclass
class Scans:
    """Scanned frames matched to simulation steps."""
    path: str
    kind: str  # "vertices" (correspondences) or "points" (unordered)
    frames: np.ndarray  # (F, N, 3) float64, m
    steps: np.ndarray  # (F,) step index k (1..T) of each frame
    skipped: int = 0  # frames at t = 0 (the start state) left out

    @property
    def num_frames(self) -> int:
        return self.frames.shape[0]


def load_scans(path, simulator: flsh_torch.RolloutSimulator) -> Scans:
    """Reads and checks a scan file (module docstring) against `simulator` (its time step,
    T and vertex count). ValueError naming the file, the key and what was expected; OSError
    when the file cannot be read."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"{path}: scan file not found")
    if not os.path.isfile(path):
        raise ValueError(f"{path}: expected a scan file (.npz), got something that is not a "
                         "regular file")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files if k in SCAN_KINDS + ("times",)}
    except (ValueError, OSError, EOFError) as error:
        raise ValueError(f"{path}: not a readable .npz file ({error})") from None
    kinds = [k for k in SCAN_KINDS if k in arrays]
    if len(kinds) != 1:
        raise ValueError(f"{path}: expected exactly one of the keys 'vertices' (F, V, 3) or "
                         f"'points' (F, N, 3), found {kinds or 'neither'}")
    kind = kinds[0]
    frames = arrays[kind]
    if frames.dtype.kind not in "fiu" or frames.ndim != 3 or frames.shape[2] != 3 \
            or frames.shape[0] < 1 or frames.shape[1] < 1:
        raise ValueError(f"{path}: key '{kind}': expected a numeric (F, N, 3) array with F, N ≥ "
                         f"1, got {frames.dtype} {frames.shape}")
    frames = frames.astype(np.float64)
    V = simulator.num_vertices
    if kind == "vertices" and frames.shape[1] != V:
        raise ValueError(f"{path}: key 'vertices': expected (F, {V}, 3) (the body model's "
                         f"{V} vertices), got {frames.shape}; unordered scans go in 'points'")
    bad = ~np.isfinite(frames) | (np.abs(frames) > MAX_COORDINATE)
    if bad.any():
        f = int(np.argwhere(bad)[0][0])
        raise ValueError(f"{path}: key '{kind}': frame {f} holds a non-finite value or one "
                         f"beyond ±{MAX_COORDINATE:g} m")
    h, T = simulator.options.time_step, simulator.steps
    skipped = 0
    if "times" in arrays:
        times = arrays["times"]
        if times.dtype.kind not in "fiu" or times.shape != (frames.shape[0],):
            raise ValueError(f"{path}: key 'times': expected ({frames.shape[0]},) numbers (one "
                             f"per frame of '{kind}'), got {times.dtype} {times.shape}")
        times = times.astype(np.float64)
        if not np.isfinite(times).all():
            raise ValueError(f"{path}: key 'times': expected finite times (s)")
        steps = np.rint(times / h)
        off = np.abs(times - steps * h) > 1e-3 * h
        if off.any():
            f = int(np.argmax(off))
            raise ValueError(f"{path}: key 'times': frame {f} at t = {times[f]:g} s is not a step "
                             f"time k·h of the simulation (h = {h:g} s)")
        keep = steps >= 1
        skipped = int((~keep).sum())
        if (steps < 0).any():
            f = int(np.argmax(steps < 0))
            raise ValueError(f"{path}: key 'times': frame {f} at t = {times[f]:g} s is before "
                             "the start (t = 0)")
        frames, steps = frames[keep], steps[keep].astype(np.int64)
    else:
        steps = np.arange(1, frames.shape[0] + 1)
    if steps.size == 0:
        raise ValueError(f"{path}: no frame after t = 0 (the start state is not fitted)")
    if steps.max() > T:
        raise ValueError(f"{path}: frames up to step {int(steps.max())} (t = "
                         f"{steps.max() * h:g} s), but the simulation has {T} steps of "
                         f"{h:g} s; lengthen its duration")
    if len(np.unique(steps)) != len(steps):
        raise ValueError(f"{path}: key 'times': two frames at one step time")
    return Scans(path, kind, frames, steps, skipped)


def material_entries(simulator: flsh_torch.RolloutSimulator, keys) -> list:
    """The material vector's entry names of `keys`: a material file key path (e.g.
    'layers.soft_tissue.E1', its '.log_value') or an entry name
    ('layers.soft_tissue.E1.log_slopes[0]'). ValueError on an unknown or repeated key."""
    keys = list(keys)
    if not keys:
        return []
    simulator._require_soft("material")
    names = simulator.material_names()
    entries = []
    for key in keys:
        if not isinstance(key, str):
            raise ValueError(f"material: expected key paths (strings), got {key!r}")
        entry = key if key in names else f"{key}.log_value"
        if entry not in names:
            known = sorted({n.rsplit(".", 1)[0] for n in names})
            raise ValueError(f"material: unknown key {key!r} (known keys: {', '.join(known)}; "
                             "or an entry such as 'layers.soft_tissue.E1.log_slopes[0]')")
        if entry in entries:
            raise ValueError(f"material: {key!r} is given twice")
        entries.append(entry)
    return entries


def minimize(objective, x0, iterations, tolerance_grad=1e-9, tolerance_change=1e-12,
             history=10, log=None):
    """L-BFGS (Nocedal & Wright, Algorithm 7.4: the two-loop recursion over the last `history`
    steps) from x0, at most `iterations` iterations, with a line search for the weak Wolfe
    conditions (bracketing: doubling, bisection, a quadratic first cut) that also steps back from
    points where `objective` is not finite (e.g. a material that is not physical). objective: a function of a float64 tensor returning
    a scalar tensor differentiable in it. Stops when the largest gradient entry is ≤
    tolerance_grad, the loss changes (or the direction promises to change it) by less than
    tolerance_change, or no step decreases it.
    Returns the minimizer found and the iterations taken. ValueError if the objective is not
    finite at x0. log: a function of one line per iteration (None: silent)."""
    def evaluate(x):
        x = x.detach().clone().requires_grad_(True)
        value = objective(x)
        if not bool(torch.isfinite(value)):
            return float("inf"), None
        (grad,) = torch.autograd.grad(value, x)
        return float(value), grad.detach()

    x = x0.detach().clone()
    f, g = evaluate(x)
    if g is None:
        raise ValueError("minimize: the objective is not finite at the start")
    steps, changes = [], []  # s_k and y_k of the last `history` iterations
    taken = 0
    for _ in range(iterations):
        if float(g.abs().max()) <= tolerance_grad:
            break
        d = _two_loop(g, steps, changes)
        gtd = float(g @ d)
        if not gtd < 0.0:  # not a descent direction: restart from the gradient
            steps.clear()
            changes.clear()
            d = _two_loop(g, steps, changes)
            gtd = float(g @ d)
        if -gtd < tolerance_change:  # the decrease this direction promises is below resolution
            break
        # Weak Wolfe by bracketing (Lewis & Overton): t too long (no sufficient decrease, or
        # not finite) bounds it above, t too short (the slope still steep) below.
        t, low, high, best = 1.0, 0.0, float("inf"), None
        shortest = 1e-14 * (1.0 + float(x.abs().max())) / max(float(d.abs().max()), 1e-300)
        for _ in range(50):
            if t < shortest:  # a step below round-off of x
                break
            f_new, g_new = evaluate(x + t * d)
            if g_new is None or f_new > f + 1e-4 * t * gtd:
                high = t
                if low == 0.0 and g_new is not None:  # the quadratic's minimum in [t/10, t/2]
                    t = min(max(-gtd * t * t / (2.0 * (f_new - f - gtd * t)), 0.1 * t), 0.5 * t)
                else:
                    t = 0.5 * (low + high)
                continue
            best = (t, f_new, g_new)
            if float(g_new @ d) >= 0.9 * gtd:
                break
            low = t
            t = 2.0 * low if high == float("inf") else 0.5 * (low + high)
        accepted = best is not None
        if accepted:
            t, f_new, g_new = best
        if not accepted:
            if log:
                log("L-BFGS: no step along the direction decreases the loss; stopping")
            break
        s, y = t * d, g_new - g
        if float(s @ y) > 1e-12 * float(s @ s) ** 0.5 * float(y @ y) ** 0.5:
            steps.append(s)
            changes.append(y)
            if len(steps) > history:
                steps.pop(0)
                changes.pop(0)
        x, f_old, f, g = x + s, f, f_new, g_new
        taken += 1
        if log:
            log(f"L-BFGS iteration {taken}: loss {f:.9g}, largest gradient entry "
                f"{float(g.abs().max()):.3g}, step {t:.3g}")
        if abs(f_old - f) < tolerance_change:
            break
    return x, taken


def _two_loop(g, steps, changes):
    """-H g by the L-BFGS two-loop recursion (H₀ = (sᵀy / yᵀy) I); without any pair the
    gradient step scaled to at most unit length in the 1-norm."""
    if not steps:
        return -g * min(1.0, 1.0 / max(float(g.abs().sum()), 1e-300))
    q = g.clone()
    alphas = []
    for s, y in zip(reversed(steps), reversed(changes)):
        alpha = float(s @ q) / float(y @ s)
        q -= alpha * y
        alphas.append(alpha)
    s, y = steps[-1], changes[-1]
    r = q * (float(s @ y) / float(y @ y))
    for (s, y), alpha in zip(zip(steps, changes), reversed(alphas)):
        beta = float(y @ r) / float(y @ s)
        r += (alpha - beta) * s
    return -r


# with_material's message for coefficients that are not physical (MaterialModel::setParameters).
_NOT_PHYSICAL = "MaterialModel::setParameters"


class _NotPhysical(Exception):
    pass


@dataclass
class FitResult:
    """What fit_scans found. The unknowns are the fitted β components (absolute values) and,
    per material entry, the offset added to its log-coefficient (a log-factor: exp(offset) is
    the factor on the coefficient)."""
    names: list  # of the unknowns: 'betas[k]' and material entry names
    start: np.ndarray
    estimate: np.ndarray
    betas: np.ndarray  # (K,) fitted shape
    material: np.ndarray | None  # (P,) fitted material vector (soft models)
    loss: str  # "vertices" or "points"
    start_loss: float
    final_loss: float
    start_rms: float  # m: RMS scan-to-surface distance at the start
    final_rms: float  # m: at the estimate
    iterations: int
    evaluations: int  # simulations with their gradients
    rejected: int  # of them at materials that are not physical (infinite loss)
    seconds: float
    vertices: np.ndarray = field(repr=False)  # (T, V, 3) the fitted simulation's surface
    simulator: flsh_torch.RolloutSimulator = field(repr=False)

    def save_material(self, path) -> None:
        """Writes the fitted material as a material file (soft models)."""
        if self.material is None:
            raise ValueError("save_material: the skeleton model has no soft-tissue material")
        self.simulator._default_avatar.with_material(self.material).save_material_file(path)

    def summary(self) -> dict:
        """The figures as plain JSON values: per fitted β component its start and fit; per
        material entry its start and fitted log-coefficient and the factor between them."""
        shape, material = {}, {}
        own = None if self.material is None else self.simulator.own_material()
        names = [] if self.material is None else self.simulator.material_names()
        for n, s, e in zip(self.names, self.start, self.estimate):
            if n.startswith("betas["):
                shape[n] = {"start": float(s), "fit": float(e)}
            else:
                a = float(own[names.index(n)])
                material[n] = {"start": a, "fit": a + float(e), "factor": float(np.exp(e - s))}
        return {
            "loss": self.loss, "shape": shape, "material": material,
            "betas": self.betas.tolist(), "start_loss": self.start_loss,
            "final_loss": self.final_loss, "start_rms_mm": 1e3 * self.start_rms,
            "final_rms_mm": 1e3 * self.final_rms, "iterations": self.iterations,
            "evaluations": self.evaluations, "rejected": self.rejected, "fit_seconds": self.seconds}


def fit_scans(simulator: flsh_torch.RolloutSimulator, scans: Scans, *, betas: int = 0,
              material=(), iterations: int = 30, noise: float = 0.002, log=None) -> FitResult:
    """Fits the first `betas` shape components (from the simulator's shape) and the material
    entries `material` (keys or entry names, material_entries; soft models) so that the
    simulated surface matches `scans` (load_scans), by at most `iterations` L-BFGS iterations.
    noise (m) scales the loss. log: a function of one line (None: silent). ValueError on
    nothing to fit or bad settings."""
    K = simulator.num_betas
    if isinstance(betas, bool) or not isinstance(betas, (int, np.integer)) or not 0 <= betas <= K:
        raise ValueError(f"betas: expected the number of leading shape components to fit, an "
                         f"integer in [0, {K}], got {betas!r}")
    entries = material_entries(simulator, material)
    if betas == 0 and not entries:
        raise ValueError("nothing to fit: give betas > 0 or material keys")
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) \
            or iterations < 1:
        raise ValueError(f"iterations: expected an integer ≥ 1, got {iterations!r}")
    if not (isinstance(noise, (int, float)) and np.isfinite(noise) and noise > 0):
        raise ValueError(f"noise: expected a positive length (m), got {noise!r}")
    log = log or (lambda line: None)

    base_betas = torch.tensor(np.asarray(simulator.default_betas, float))
    own = torch.tensor(simulator.own_material()) if simulator.soft_tissue else None
    names = simulator.material_names() if entries else []
    index = torch.tensor([names.index(e) for e in entries], dtype=torch.long)
    faces = torch.tensor(np.asarray(simulator.body.faces), dtype=torch.long)
    target = torch.from_numpy(scans.frames)
    rows = torch.from_numpy(scans.steps - 1)

    def inputs(x):
        b = base_betas.index_put((torch.arange(betas),), x[:betas]) if betas else None
        m = own.index_put((index,), own[index] + x[betas:]) if entries else None
        return b, m

    def squared_distances(x):
        b, m = inputs(x)
        try:
            _, v = flsh_torch.simulate(simulator, betas=b, material=m, vertices=True)
        except ValueError as error:
            if m is not None and str(error).startswith(_NOT_PHYSICAL):
                raise _NotPhysical(str(error)) from None
            raise
        if scans.kind == "points":
            return flsh_torch.point_to_surface(target, v[rows], faces), v
        return ((v[rows] - target) ** 2).sum(-1), v

    evaluations = rejected = 0

    def objective(x):
        # A material the line search tried that is not physical (e.g. a Poisson ratio the
        # moduli no longer allow) is infinitely bad: the line search steps back from it.
        nonlocal evaluations, rejected
        evaluations += 1
        try:
            d2, _ = squared_distances(x)
        except _NotPhysical:
            rejected += 1
            return torch.tensor(float("inf"), dtype=torch.float64)
        return d2.mean() / noise ** 2

    x0 = torch.cat([base_betas[:betas], torch.zeros(len(entries), dtype=torch.float64)])
    with torch.no_grad():
        d2, _ = squared_distances(x0)
    start_loss, start_rms = float(d2.mean()) / noise ** 2, float(d2.mean().sqrt())
    log(f"fitting {betas} shape component(s) and {len(entries)} material entr"
        f"{'y' if len(entries) == 1 else 'ies'} to {scans.num_frames} frame(s) of "
        f"{scans.kind} ({scans.path}): start RMS {1e3 * start_rms:.3f} mm")
    started = time.perf_counter()
    x, lbfgs_iterations = minimize(objective, x0, iterations, log=log)
    seconds = time.perf_counter() - started
    with torch.no_grad():
        d2, v = squared_distances(x)
    final_loss, final_rms = float(d2.mean()) / noise ** 2, float(d2.mean().sqrt())
    b, m = inputs(x)
    result = FitResult(
        names=[f"betas[{k}]" for k in range(betas)] + entries, start=x0.numpy(),
        estimate=x.numpy(), betas=(base_betas if b is None else b).numpy(),
        material=None if not simulator.soft_tissue else
        (own if m is None else m).detach().numpy(),
        loss=scans.kind, start_loss=start_loss, final_loss=final_loss, start_rms=start_rms,
        final_rms=final_rms, iterations=int(lbfgs_iterations), evaluations=evaluations,
        rejected=rejected, seconds=seconds, vertices=v.numpy(), simulator=simulator)
    log(f"fit: RMS {1e3 * start_rms:.3f} → {1e3 * final_rms:.3f} mm, {result.iterations} L-BFGS "
        f"iterations, {evaluations} simulations with gradients ({rejected} at materials that are "
        f"not physical), {seconds:.1f} s")
    return result
