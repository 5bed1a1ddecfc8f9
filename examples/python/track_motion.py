"""A synthetic avatar tracks a built-in motion with the articulated-skeleton model, standing on
the ground, stepped by a flsh.Scene (Newton on backward Euler). Writes a PNG sheet of a few
frames and prints a summary (steps per second, contacts, how closely the pose follows the
motion).

Usage:
    PYTHONPATH=build/python /usr/bin/python3 examples/python/track_motion.py \
        [--motion walk] [--seconds 1.0] [--vertices 2000] [--out track_motion_out]
"""
import argparse
import os
import time

import numpy as np

import flsh


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--motion", default="walk", help="built-in motion name or AMASS .npz")
    parser.add_argument("--seconds", type=float, default=1.0, help="simulated time, s")
    parser.add_argument("--vertices", type=int, default=2000, help="synthetic body vertices")
    parser.add_argument("--sheet-frames", type=int, default=5, help="frames shown in sheet.png")
    parser.add_argument("--out", default="track_motion_out", help="output folder")
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)

    model = flsh.make_synthetic_body(vertices=args.vertices)
    avatar = flsh.SoftAvatar(model)
    avatar.init_volumetric_data()
    motion = flsh.load_or_make_motion(args.motion, seconds=args.seconds, fps=30.0)
    options = flsh.SimulableOptions(time_step=1.0 / 60.0)
    simulable = flsh.Simulable(avatar, motion, options)

    scene = flsh.Scene()
    scene.add_simulable(simulable)
    ground_height = avatar.rest_vertices[:, 1].min()  # the soles of the rest pose
    scene.add_collider(flsh.Collider.plane(point=[0.0, ground_height, 0.0], normal=[0.0, 1.0, 0.0]))
    scene.initialize()

    steps = max(1, int(round(args.seconds / options.time_step)))
    shown = set(np.linspace(0, steps, max(1, args.sheet_frames)).round().astype(int).tolist())
    frames = [simulable.getVertices()] if 0 in shown else []
    pose_errors, contacts, iterations = [], [], []
    start = time.perf_counter()
    for n in range(1, steps + 1):
        stats = scene.step()
        if not stats.newton.converged:
            print(f"step {n}: Newton did not converge: {stats.newton.message}")
        contacts.append(stats.active_contacts)
        iterations.append(stats.newton.iterations)
        # Tracking error: the simulated pose against the mocap frame at this time.
        frame = min(motion.num_frames - 1, int(round(scene.time * motion.fps)))
        difference = (simulable.getPose() - motion.poses[frame]).reshape(24, 3)
        pose_errors.append(np.linalg.norm(difference, axis=1))
        if n in shown:
            frames.append(simulable.getVertices())
    elapsed = time.perf_counter() - start

    sheet = flsh.render_sheet(np.stack(frames), model.faces, flsh.RenderOptions(width=200, height=280))
    sheet_path = os.path.join(args.out, "sheet.png")
    flsh.write_png(sheet_path, sheet)
    lowest = simulable.getNodes()[:, 1].min() - ground_height
    print(f"{args.motion}: {steps} steps of {options.time_step:.4f} s in {elapsed:.2f} s "
          f"({steps / elapsed:.0f} steps/s), mean Newton iterations {np.mean(iterations):.1f}")
    print(f"contacts per step: mean {np.mean(contacts):.0f}, max {max(contacts)}; "
          f"lowest vertex {1000 * lowest:+.1f} mm from the ground")
    pose_errors = np.degrees(pose_errors)  # steps × 24 joints
    worst = int(pose_errors.mean(axis=0).argmax())
    print(f"|pose − mocap| per joint: mean {pose_errors.mean():.1f}°, largest on average at "
          f"{flsh.SMPL_JOINT_NAMES[worst]} ({pose_errors[:, worst].mean():.1f}°); "
          f"mass {avatar.total_mass:.1f} kg")
    print(f"wrote {sheet_path} ({sheet.width} × {sheet.height})")


if __name__ == "__main__":
    main()
