"""Workflow 2: train a small PyTorch network with a physics loss through the simulator.

A synthetic avatar walks (tracking a built-in motion) while its arms follow pose targets we do
not know: each observed sequence was simulated with the walk's targets plus a smooth arm swing
of its own (sinusoids of random amplitude and phase on the shoulders and elbows). A small MLP
sees the observed joint positions of each step (relative to the pelvis) and predicts the
corrections of the arm targets at that step; the predicted targets are simulated
(flsh.torch.simulate, differentiable by the adjoint method) and the loss is the squared
distance of the simulated joints to the observed ones, summed over steps and sequences. No
ground-truth targets enter the loss: only the physics.

Usage:
    PYTHONPATH=build/python /usr/bin/python3 examples/python/train_physics_loss.py \
        [--sequences 3] [--validation 1] [--steps 8] [--epochs 150] [--vertices 600]
"""
import argparse
import time

import numpy as np
import torch

import flsh
import flsh.torch

ARM_JOINTS = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow")


def arm_columns():
    """Columns of the 72 pose-target values that the network predicts (3 per arm joint)."""
    return [3 * flsh.smpl_joint_index(name) + c for name in ARM_JOINTS for c in range(3)]


def make_dataset(simulator, sequences, rng):
    """Observed joint trajectories (sequences, T, 24, 3) simulated with unknown arm swings."""
    base = torch.tensor(simulator.own_inputs()["pose_targets"])  # (T, 72) the walk's targets
    time_s = torch.arange(1, simulator.steps + 1, dtype=torch.float64) * simulator.options.time_step
    columns = arm_columns()
    observed = []
    for _ in range(sequences):
        amplitude = torch.tensor(rng.uniform(-0.5, 0.5, len(columns)))
        phase = torch.tensor(rng.uniform(0.0, 2 * np.pi, len(columns)))
        targets = base.clone()
        targets[:, columns] += amplitude * torch.sin(2 * np.pi * 1.5 * time_s[:, None] + phase)
        with torch.no_grad():
            observed.append(flsh.torch.simulate(simulator, pose_targets=targets))
    return base, torch.stack(observed)


class TargetNetwork(torch.nn.Module):
    """Observed joints of a step and of the next one (2 × 24 × 3, relative to the pelvis, m; the
    targets of step t show in the joints after it) → arm-target corrections of the step (rad).
    The last layer starts at zero: the first prediction is the walk's own targets."""

    def __init__(self, outputs, hidden=64):
        super().__init__()
        self.layers = torch.nn.Sequential(
            torch.nn.Linear(144, hidden), torch.nn.Tanh(), torch.nn.Linear(hidden, outputs))
        torch.nn.init.zeros_(self.layers[-1].weight)
        torch.nn.init.zeros_(self.layers[-1].bias)

    def forward(self, joints):  # (T, 24, 3) -> (T, outputs)
        relative = (joints - joints[:, :1]).reshape(joints.shape[0], 72)
        following = torch.cat([relative[1:], relative[-1:]])  # the last step repeats
        return self.layers(torch.cat([relative, following], dim=1))


def physics_loss(network, simulator, base_targets, observed):
    """Σ over sequences and steps of ‖simulated joints − observed joints‖², m²."""
    columns = arm_columns()
    loss = torch.zeros((), dtype=torch.float64)
    for sequence in observed:
        targets = base_targets.clone()
        targets[:, columns] = targets[:, columns] + network(sequence)
        loss = loss + (flsh.torch.simulate(simulator, pose_targets=targets) - sequence).square().sum()
    return loss


def train(vertices=600, steps=8, sequences=3, epochs=150, learning_rate=1e-2, seed=0,
          validation=1, log=print):
    """Trains the network on `sequences` observed sequences; returns the training loss (m²)
    of each epoch (the first before any update) and the physics loss on `validation` other
    sequences before and after training."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    body = flsh.make_synthetic_body(vertices=vertices)
    simulator = flsh.torch.RolloutSimulator(
        body, flsh.make_builtin_motion("walk", seconds=1.0, fps=30.0), steps=steps,
        newton=flsh.NewtonOptions(gradient_tolerance=1e-9))
    base_targets, observed = make_dataset(simulator, sequences + validation, rng)
    observed, held_out = observed[:sequences], observed[sequences:]
    network = TargetNetwork(len(arm_columns())).double()
    with torch.no_grad():
        validation_before = physics_loss(network, simulator, base_targets, held_out).item()
    optimizer = torch.optim.Adam(network.parameters(), lr=learning_rate)
    losses = []
    for epoch in range(epochs + 1):
        optimizer.zero_grad()
        loss = physics_loss(network, simulator, base_targets, observed)
        losses.append(loss.item())
        if epoch % max(1, epochs // 10) == 0 or epoch == epochs:
            log(f"epoch {epoch:3d}  physics loss {loss.item():.3e} m²")
        if epoch < epochs:
            loss.backward()
            optimizer.step()
    with torch.no_grad():
        validation_after = physics_loss(network, simulator, base_targets, held_out).item()
    if validation:
        log(f"held-out sequences: physics loss {validation_before:.3e} -> "
            f"{validation_after:.3e} m²")
    return losses, (validation_before, validation_after)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--vertices", type=int, default=600, help="synthetic body vertices")
    parser.add_argument("--steps", type=int, default=8, help="simulated steps per sequence")
    parser.add_argument("--sequences", type=int, default=3, help="observed sequences")
    parser.add_argument("--validation", type=int, default=1, help="held-out sequences")
    parser.add_argument("--epochs", type=int, default=150, help="Adam updates")
    parser.add_argument("--lr", type=float, default=1e-2, help="Adam learning rate")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    start = time.perf_counter()
    losses, _ = train(args.vertices, args.steps, args.sequences, args.epochs, args.lr, args.seed,
                      args.validation)
    print(f"loss {losses[0]:.3e} -> {losses[-1]:.3e} m² ({losses[-1] / losses[0]:.1%} of the "
          f"start) in {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
