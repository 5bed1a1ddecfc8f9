"""Workflow 3: recover the body shape β and the take-off velocity of a simulated jump from its
joint trajectory alone.

A synthetic avatar of unknown shape β stands on the ground and takes off with an unknown
velocity: a linear velocity v (m/s) and a spin ω (rad/s, world frame, about the pelvis), i.e.
the rigid initial velocity per bone b [v + ω × (t_b − t_0), ω] of the simulable's initial
velocity (flsh.Simulable.set_velocity layout). In the air it keeps tracking the built-in "jump"
motion's joint rotations (tracking springs) while its root is free (root stiffness 0), so the
flight is ballistic, and lands on the ground plane its soles stood on (T = 30 steps of 1/60 s:
take-off, flight, landing). Only the joint positions of the T
simulated steps are observed. β, v and ω are found by L-BFGS on the squared joint error, with
gradients through the simulation (flsh.torch.simulate, adjoint method) and through the initial
pose's joints (flsh.torch.smpl: t_b − t_0 moves with β).

Usage:
    PYTHONPATH=build/python /usr/bin/python3 examples/python/recover_jump.py \
        [--steps 30] [--vertices 600] [--iterations 300]
"""
import argparse
import time

import numpy as np
import torch

import flsh
import flsh.torch


class JumpProblem:
    """The simulator of the jump and the map (β, v, ω) → observed joints (T, 24, 3)."""

    # Shape components that a joint trajectory can tell apart: the skeleton's (height, weight,
    # leg and arm length, shoulder and hip width). The others (belly, chest, head size,
    # muscularity) move no joint by more than 8 mm per unit of β (head size 0.2 mm): they are
    # soft-tissue shape, not seen by joints, and stay at zero here.
    shape_components = 6

    def __init__(self, body, steps=30, floor_betas=None):
        self.body = body
        motion = flsh.make_builtin_motion("jump", seconds=1.0, fps=30.0)
        # The ground is known from the scene: where the soles of the jumper (shape floor_betas,
        # None = the default shape) stood before the take-off.
        avatar = flsh.SoftAvatar(self.body, floor_betas)
        avatar.init_volumetric_data()
        standing = flsh.Simulable(avatar, motion)
        standing.initialize()
        ground = flsh.Collider.plane(point=[0.0, standing.get_nodes()[:, 1].min(), 0.0],
                                     normal=[0.0, 1.0, 0.0])
        self.simulator = flsh.torch.RolloutSimulator(
            self.body, motion, steps=steps, colliders=[ground],
            options=flsh.SimulableOptions(root_stiffness=0.0),  # the root flies freely
            newton=flsh.NewtonOptions(gradient_tolerance=1e-10, max_iterations=50))
        self.first_pose = torch.tensor(motion.poses[0])  # the initial state's pose (72,)
        self.first_trans = torch.tensor(motion.trans[0])  # (3,) m
        # Preconditioner: β = shape_basis · z whitens the rest joints' response to those
        # components, dJ/dβ = U S Vᵀ (72 × 6) → shape_basis = V S⁻¹ · 1 cm, so that a unit of z
        # moves the joints by 1 cm along orthonormal patterns. (In β itself the sensitivities
        # differ 20-fold, which slows L-BFGS down.)
        joints_shape = np.einsum("jv,vck->jck", self.body.J_regressor,
                                 self.body.shapedirs).reshape(72, -1)
        _, singular_values, vt = np.linalg.svd(joints_shape[:, :self.shape_components],
                                               full_matrices=False)
        self.shape_basis = torch.tensor(0.01 * vt.T / singular_values)  # (6, 6)

    def initial_velocity(self, betas, linear, spin):
        """Per bone [v + ω × (t_b − t_0), ω] (144,), with t_b the joints of the first frame."""
        _, joints = flsh.torch.smpl(self.body, betas, self.first_pose, self.first_trans)
        arms = joints - joints[:1]
        linear_per_bone = linear + torch.linalg.cross(spin.expand(24, 3), arms)
        return torch.cat([linear_per_bone, spin.expand(24, 3)], dim=1).reshape(144)

    def joints(self, betas, linear, spin):
        return flsh.torch.simulate(self.simulator, betas=betas,
                                   initial_velocity=self.initial_velocity(betas, linear, spin))


def recover(vertices=600, steps=30, iterations=300, seed=1, log=print):
    """Simulates a jump with random β (skeletal components), v, ω, then recovers them from its
    joints; returns a dict of the truth, the estimates, the first and final loss (m²), the
    number of loss evaluations and the true jump's ground contacts at its last step."""
    rng = np.random.default_rng(seed)
    body = flsh.make_synthetic_body(vertices=vertices)
    betas = np.zeros(body.num_betas)
    betas[:JumpProblem.shape_components] = rng.uniform(-1.0, 1.0, JumpProblem.shape_components)
    problem = JumpProblem(body, steps, floor_betas=betas)
    K = problem.simulator.num_betas
    truth = {"betas": torch.tensor(betas),
             "linear": torch.tensor([rng.uniform(-0.5, 0.5), rng.uniform(1.5, 2.5),
                                     rng.uniform(0.5, 1.0)]),
             "spin": torch.tensor(rng.uniform(-1.5, 1.5, 3))}
    with torch.no_grad():
        observed = problem.joints(truth["betas"], truth["linear"], truth["spin"])
        true_velocity = problem.initial_velocity(truth["betas"], truth["linear"], truth["spin"])
    # Vertices touching the ground at the last step of the true jump (the landing).
    landing_contacts = problem.simulator.rollout(
        betas, initial_velocity=true_velocity.numpy()).simulable.active_contacts
    log(f"true jump: {landing_contacts} vertices on the ground at the last of {steps} steps")

    # Start: the default shape, standing still. Unknowns: z (β = shape_basis · z), v, ω.
    shape_z = torch.zeros(problem.shape_components, dtype=torch.float64, requires_grad=True)
    linear = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    spin = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    optimizer = torch.optim.LBFGS([shape_z, linear, spin], lr=1.0, max_iter=iterations,
                                  tolerance_grad=1e-14, tolerance_change=1e-20, history_size=20,
                                  line_search_fn="strong_wolfe")
    evaluations = []

    def loss_now():
        betas = problem.shape_basis @ shape_z  # (6,): flsh pads the others with zeros
        return (problem.joints(betas, linear, spin) - observed).square().sum()

    def closure():
        optimizer.zero_grad()
        loss = loss_now()
        loss.backward()
        evaluations.append(loss.item())
        if len(evaluations) % 10 == 1:
            log(f"evaluation {len(evaluations):3d}  joint loss {loss.item():.3e} m²")
        return loss

    optimizer.step(closure)
    with torch.no_grad():
        final = loss_now().item()
        found_betas = np.zeros(K)
        found_betas[:problem.shape_components] = (problem.shape_basis @ shape_z).numpy()
        estimate = {"betas": found_betas,
                    "linear": linear.detach().numpy().copy(), "spin": spin.detach().numpy().copy()}
    log(f"final joint loss {final:.3e} m² after {len(evaluations)} evaluations")
    result = {"truth": {k: v.numpy() for k, v in truth.items()}, "estimate": estimate,
              "initial_loss": evaluations[0], "final_loss": final,
              "evaluations": len(evaluations), "landing_contacts": landing_contacts}
    for name in truth:
        error = np.abs(result["estimate"][name] - result["truth"][name]).max()
        log(f"{name:7s} truth {np.array2string(result['truth'][name], precision=3)}\n"
            f"        found {np.array2string(result['estimate'][name], precision=3)}"
            f"  (max error {error:.1e})")
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--vertices", type=int, default=600, help="synthetic body vertices")
    parser.add_argument("--steps", type=int, default=30, help="observed steps (h = 1/60 s)")
    parser.add_argument("--iterations", type=int, default=300, help="L-BFGS iterations")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    start = time.perf_counter()
    recover(args.vertices, args.steps, args.iterations, args.seed)
    print(f"done in {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
