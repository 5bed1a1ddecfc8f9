"""A ball hits the belly of a standing avatar: a sphere collider moves along −z at belly height
into the front of the body and back, which tracks the built-in "stand" motion on the ground.
Writes a PNG sheet (body and ball) and prints how far the body is pushed. With --soft the avatar
is the FEM soft skeleton (docs/fem.md), with --rom the ROM soft skeleton (docs/rom.md: the
default modal basis, or --handles surface handles; elastic and inertial cubature): the belly gives way, the
sheet colours the body by the soft-tissue displacement |u| and the largest displacement is
printed.

The synthetic body's pelvis joint is at the origin, its belly front at z ≈ +0.11 m, y ≈ 0.05 m.

Usage:
    PYTHONPATH=build/python /usr/bin/python3 examples/python/ball_belly.py \
        [--speed 3.0] [--radius 0.12] [--seconds 0.6] [--vertices 2000] [--out ball_belly_out]
        [--soft | --rom [--handles 87]] [--resolution 1.0] [--cache DIR]
"""
import argparse
import os

import numpy as np

import flsh


def sphere_mesh(center, radius, rings=10, segments=16):
    """A latitude-longitude sphere: vertices (N, 3), faces (F, 3)."""
    theta = np.linspace(0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    vertices = np.vstack([[0, 1, 0], ring, [0, -1, 0]]) * radius + center
    faces, bottom = [], len(vertices) - 1
    for j in range(segments):
        k = (j + 1) % segments
        faces.append([0, 1 + k, 1 + j])
        for r in range(rings - 2):
            a, b = 1 + r * segments + j, 1 + r * segments + k
            faces += [[a, b, b + segments], [a, b + segments, a + segments]]
        last = 1 + (rings - 2) * segments
        faces.append([bottom, last + j, last + k])
    return vertices, np.array(faces, dtype=np.int32)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--speed", type=float, default=3.0, help="ball speed along −z, m/s")
    parser.add_argument("--radius", type=float, default=0.12, help="ball radius, m")
    parser.add_argument("--seconds", type=float, default=0.6, help="simulated time, s")
    parser.add_argument("--vertices", type=int, default=2000, help="synthetic body vertices")
    parser.add_argument("--sheet-frames", type=int, default=5, help="frames shown in sheet.png")
    parser.add_argument("--out", default="ball_belly_out", help="output folder")
    model_group = parser.add_mutually_exclusive_group()
    model_group.add_argument("--soft", action="store_true",
                             help="FEM soft tissue instead of the skeleton")
    model_group.add_argument("--rom", action="store_true",
                             help="ROM soft tissue (reduced basis, cubatures) instead of the skeleton")
    parser.add_argument("--handles", type=int, default=None,
                        help="ROM handles (--rom; default: the modal basis, no handles)")
    parser.add_argument("--resolution", type=float, default=1.0,
                        help="tet-mesh resolution (--soft, --rom)")
    parser.add_argument("--cache", default="",
                        help="avatar cache folder (--soft, --rom; default ~/.cache/flsh)")
    args = parser.parse_args()
    soft = args.soft or args.rom
    os.makedirs(args.out, exist_ok=True)

    model = flsh.make_synthetic_body(vertices=args.vertices)
    if args.soft:
        avatar = flsh.SoftAvatar(model, resolution=args.resolution, cache_dir=args.cache)
        avatar.enable_soft_tissue()
    elif args.rom:
        avatar = flsh.SoftAvatar(model, resolution=args.resolution, cache_dir=args.cache,
                                 handles=args.handles)
        avatar.enable_soft_tissue()
        avatar.enable_reduced_model()
        avatar.enable_elastic_cubature()
        avatar.enable_inertial_cubature()
    else:
        avatar = flsh.SoftAvatar(model)
    avatar.init_volumetric_data()
    if args.rom:
        reduced = avatar.reduced_data
        spans = [f"{n} {what}" for n, what in ((reduced.num_modes, "modes"),
                                               (reduced.num_handles, "handles")) if n]
        print(f"ROM: {', '.join(spans)}; elastic cubature "
              f"{len(reduced.elastic_cubature)} tets (held-out error "
              f"{100 * reduced.elastic_test_error:.2f} %), inertial cubature "
              f"{len(reduced.inertial_cubature)} tets ({100 * reduced.inertial_test_error:.2f} %); "
              f"reduced data {'from the cache' if avatar.reduced_build_report['from_cache'] else 'built'}")
    motion = flsh.make_builtin_motion("stand", seconds=args.seconds, fps=30.0)
    time_step = 1.0 / 30.0 if soft else 1.0 / 60.0
    simulable = flsh.Simulable(avatar, motion, flsh.SimulableOptions(time_step=time_step))

    belly = np.array([0.0, 0.05, 0.11])  # front of the belly, m
    # The ball starts 0.15 s of flight in front of the belly, presses 6 cm past the rest
    # surface (a scripted collider is not stopped by the body), then goes back the same way.
    start = belly + [0.0, 0.0, args.radius + 0.15 * args.speed]
    turn = 0.15 + 0.06 / args.speed
    ball = flsh.Collider.sphere(start, args.radius)
    ball.path = flsh.ColliderPath([0.0, turn, 2 * turn],
                                  [[0.0, 0.0, 0.0], [0.0, 0.0, -args.speed * turn], [0.0, 0.0, 0.0]])
    ball.name = "ball"
    ground_height = avatar.rest_vertices[:, 1].min()
    scene = flsh.Scene()
    scene.add_simulable(simulable)
    scene.add_collider(flsh.Collider.plane(point=[0.0, ground_height, 0.0], normal=[0, 1, 0]))
    scene.add_collider(ball)
    scene.initialize()

    pelvis_rest = simulable.bone_positions[0].copy()
    steps = max(1, int(round(args.seconds / simulable.options.time_step)))
    shown = set(np.linspace(0, steps, max(1, args.sheet_frames)).round().astype(int).tolist())
    frames, colors = [], []
    ball_vertices, ball_faces = sphere_mesh(np.zeros(3), args.radius)
    faces = np.vstack([model.faces, ball_faces + model.num_vertices])
    color = np.vstack([np.tile([0.75, 0.72, 0.68], (model.num_vertices, 1)),
                       np.tile([0.85, 0.25, 0.2], (len(ball_vertices), 1))])

    magnitudes = []

    def snapshot():
        center = start + ball.path.offset_at(scene.time)
        frames.append(np.vstack([simulable.getVertices(), ball_vertices + center]))
        magnitudes.append(np.linalg.norm(simulable.getSoftTissueDisplacements(), axis=1))

    if 0 in shown:
        snapshot()
    max_push, max_contacts, deepest = 0.0, 0, 0.0
    for n in range(1, steps + 1):
        stats = scene.step()
        if not stats.newton.converged:
            print(f"step {n}: Newton did not converge: {stats.newton.message}")
        max_contacts = max(max_contacts, stats.active_contacts)
        max_push = max(max_push, pelvis_rest[2] - simulable.bone_positions[0][2])
        deepest = min(deepest, ball.signed_distance(simulable.getNodes(), scene.time).min())
        if n in shown:
            snapshot()

    options = flsh.RenderOptions(width=240, height=280, view_direction=[-1.0, 0.0, -0.3])
    largest = max(m.max() for m in magnitudes)
    if soft:  # body coloured by |u| on one scale for the sheet, the ball stays red
        color = np.stack([np.vstack([flsh.displacement_colors(m, largest), color[model.num_vertices:]])
                          for m in magnitudes])
    sheet = flsh.render_sheet(np.stack(frames), faces, options, colors=color)
    sheet_path = os.path.join(args.out, "sheet.png")
    flsh.write_png(sheet_path, sheet)
    print(f"ball r = {args.radius} m at {args.speed} m/s: {steps} steps, up to {max_contacts} "
          f"contacts; pelvis pushed back by up to {100 * max_push:.1f} cm; deepest ball "
          f"penetration {1000 * -deepest:.1f} mm")
    if soft:
        print(f"soft tissue: largest displacement |u| {1000 * largest:.1f} mm in the sheet "
              f"(viridis: dark purple 0, yellow {1000 * largest:.1f} mm)")
    print(f"wrote {sheet_path} ({sheet.width} × {sheet.height})")


if __name__ == "__main__":
    main()
