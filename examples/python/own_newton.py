"""The FLSH paper's solver example: a Newton loop written in Python on top of a Simulable's
runtime API, stepping an avatar that tracks a motion on the ground.

Each time step is preUpdate(), then Newton on E = getDynamicEnergyScalar() +
getPotentialEnergyScalar() with the gradient vectors and (positive-semidefinite) Hessian
matrices, kinematic DoFs fixed by fixVectorKinematic / fixMatrixKinematic, the linear system
solved by scipy.sparse.linalg.spsolve, and a backtracking line search that tries a step with
pushState / updateState and undoes it with popState; then postUpdate(). The loop is the same
algorithm as flsh's C++ newton_solve, so the result matches flsh.Scene.step().

Usage:
    PYTHONPATH=build/python /usr/bin/python3 examples/python/own_newton.py \
        [--motion walk] [--seconds 0.5] [--vertices 1000] [--out own_newton_out]
"""
import argparse
import os
import time

import numpy as np
import scipy.sparse.linalg

import flsh


def total_energy(sim):
    return sim.getDynamicEnergyScalar() + sim.getPotentialEnergyScalar()


def newton_step(sim, max_iterations=30, gradient_tolerance=1e-6, step_tolerance=1e-9,
                armijo=1e-4, max_line_search_steps=25):
    """One backward-Euler step of `sim`. Returns (converged, iterations)."""
    sim.preUpdate()
    energy = total_energy(sim)
    initial_norm, last_step = None, np.inf
    converged, iteration = False, 0
    for iteration in range(max_iterations + 1):
        g = sim.fixVectorKinematic(sim.getDynamicGradientVector() + sim.getPotentialGradientVector())
        norm = np.abs(g).max()
        initial_norm = norm if initial_norm is None else initial_norm
        if norm <= gradient_tolerance * max(1.0, initial_norm) or \
                (iteration > 0 and last_step <= step_tolerance):
            converged = True
            break
        if iteration == max_iterations:
            break
        H = sim.fixMatrixKinematic(sim.getDynamicHessianTripletVector(psd=True) +
                                   sim.getPotentialHessianTripletVector(psd=True))
        dq = scipy.sparse.linalg.spsolve(H, -g)
        slope = g @ dq
        if not (np.all(np.isfinite(dq)) and slope < 0):
            # Singular H: scaled steepest descent still goes downhill.
            dq = -g / np.abs(H.diagonal()).mean()
            slope = g @ dq
        alpha = 1.0
        for trial in range(max_line_search_steps + 1):
            sim.pushState()
            sim.updateState(alpha * dq)
            trial_energy = total_energy(sim)
            sim.popState()  # back to the start of the line search either way
            if np.isfinite(trial_energy) and \
                    trial_energy <= energy + armijo * alpha * slope + 1e-12 * abs(energy):
                sim.updateState(alpha * dq)
                energy = trial_energy
                break
            alpha *= 0.5
        else:
            break  # no decrease: keep the state
        last_step = alpha * np.abs(dq).max()
    sim.postUpdate()
    return converged, iteration


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--motion", default="walk", help="built-in motion name or AMASS .npz")
    parser.add_argument("--seconds", type=float, default=0.5, help="simulated time, s")
    parser.add_argument("--vertices", type=int, default=1000, help="synthetic body vertices")
    parser.add_argument("--out", default="own_newton_out", help="output folder")
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)

    model = flsh.make_synthetic_body(vertices=args.vertices)
    avatar = flsh.SoftAvatar(model)
    avatar.init_volumetric_data()
    motion = flsh.load_or_make_motion(args.motion, seconds=args.seconds, fps=30.0)
    sim = flsh.Simulable(avatar, motion, flsh.SimulableOptions(time_step=1.0 / 60.0))
    ground_height = avatar.rest_vertices[:, 1].min()
    sim.setColliders([flsh.Collider.plane(point=[0.0, ground_height, 0.0], normal=[0, 1, 0])])
    sim.initialize()

    steps = max(1, int(round(args.seconds / sim.options.time_step)))
    frames, iterations = [sim.getVertices()], []
    start = time.perf_counter()
    for n in range(steps):
        converged, its = newton_step(sim)
        if not converged:
            print(f"step {n + 1}: Newton did not converge in {its} iterations")
        iterations.append(its)
        if (n + 1) % max(1, steps // 4) == 0:
            frames.append(sim.getVertices())
    elapsed = time.perf_counter() - start

    sheet = flsh.render_sheet(np.stack(frames), model.faces, flsh.RenderOptions(width=200, height=280))
    sheet_path = os.path.join(args.out, "sheet.png")
    flsh.write_png(sheet_path, sheet)
    print(f"{steps} steps with a Python Newton loop in {elapsed:.2f} s "
          f"({steps / elapsed:.0f} steps/s), iterations per step: mean {np.mean(iterations):.1f}, "
          f"max {max(iterations)}")
    print(f"final time {sim.time:.3f} s, energy {total_energy(sim):.4f} J, "
          f"contacts {sim.active_contacts}")
    print(f"wrote {sheet_path} ({sheet.width} × {sheet.height})")


if __name__ == "__main__":
    main()
