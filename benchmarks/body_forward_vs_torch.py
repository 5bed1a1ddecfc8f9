"""flsh's SMPL forward pass (C++) against a plain-PyTorch implementation (flsh.smpl_torch).

Usage:
    PYTHONPATH=build/python /usr/bin/python3 benchmarks/body_forward_vs_torch.py [--repeats N]
        [--threads N]   (threads of both flsh/OpenMP and torch; default os.cpu_count())

Cases, each on two models of SMPL's size (6890 vertices, 10 shape components):
  * "synthetic": flsh's synthetic body (its pose blend shapes are what its generator makes);
  * "dense posedirs": the same body with dense random pose blend shapes (V × 3 × 207), like the
    real SMPL files; built in numpy, written with np.savez, read with flsh.load_body_model.
  (a) one frame;  (b) the same in PyTorch (float64, no_grad, torch threads = os.cpu_count());
  (c) one frame with the Jacobians d(vertices, joints)/d(betas, pose, trans): flsh analytic vs
      torch forward-mode automatic differentiation of the reference (vectorized over the 85
      input directions, its fastest option here);
  (d) a batch of 100 frames (flsh.pose_body_batch vs one batched torch call), per frame.
Before timing, each pair is checked to agree (max abs difference printed). Timings are medians
of repeated runs after a warm-up, in milliseconds per frame; speed-up = torch time / flsh time.
"""
import argparse
import os
import statistics
import sys
import tempfile
import time

import numpy as np

# flsh and torch are imported in main(), after OMP_NUM_THREADS is set from --threads: OpenMP
# reads it once, when the first library using it loads.
flsh = torch = smpl_torch = None

BATCH_FRAMES = 100
AGREEMENT_TOLERANCE = 1e-8  # m (or m/rad for Jacobians); float64 on both sides


def median_ms(fn, repeats, min_seconds=0.3):
    """Median wall time of fn() in ms over at least `repeats` runs and `min_seconds`, after
    one warm-up run."""
    fn()
    times = []
    start = time.perf_counter()
    while len(times) < repeats or time.perf_counter() - start < min_seconds:
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def dense_posedirs_model(body, directory, seed=7):
    """The body with dense random pose blend shapes of SMPL's size, through an np.savez file."""
    rng = np.random.default_rng(seed)
    V = body.num_vertices
    posedirs = rng.normal(0.0, 1e-3, (V, 3, 207))  # m per unit of (R − I); SMPL's scale
    kintree = np.stack([body.parents, np.arange(24)])
    path = os.path.join(directory, "dense_posedirs.npz")
    np.savez(path, v_template=body.v_template, shapedirs=body.shapedirs, posedirs=posedirs,
             J_regressor=body.J_regressor, weights=body.weights, kintree_table=kintree,
             f=body.faces)
    return flsh.load_body_model(path)


def torch_jacobian_function(reference):
    """d(vertices, joints)/d(betas, pose, trans) of one frame by torch forward-mode AD."""

    def frame(betas, pose, trans):
        v, j, _, _ = reference.forward(betas, pose[None], trans[None])
        return v[0], j[0]

    def jacobian(betas, pose, trans):
        return torch.autograd.functional.jacobian(
            frame, (betas, pose, trans), vectorize=True, strategy="forward-mode")

    return jacobian


def check(name, a, b):
    diff = float(np.abs(np.asarray(a) - np.asarray(b)).max())
    if not diff <= AGREEMENT_TOLERANCE:
        sys.exit(f"{name}: flsh and torch disagree, max abs diff {diff:.3e}")
    return diff


def run_model(label, model, repeats, rng):
    reference = smpl_torch.SmplTorch.from_flsh(model)
    K = model.num_betas
    betas = rng.normal(0.0, 1.0, K)
    pose = rng.normal(0.0, 0.4, 72)
    trans = rng.normal(0.0, 0.3, 3)
    poses = rng.normal(0.0, 0.4, (BATCH_FRAMES, 72))
    transes = rng.normal(0.0, 0.3, (BATCH_FRAMES, 3))
    tb, tp, tt = (torch.tensor(a) for a in (betas, pose, trans))
    tposes, ttranses = torch.tensor(poses), torch.tensor(transes)
    jacobian = torch_jacobian_function(reference)

    # Agreement first: the timings below compare computations that give the same numbers.
    diffs = {}
    posed = flsh.pose_body(model, betas, pose, trans, jacobians=True)
    with torch.no_grad():
        v, j, _, _ = reference.forward(tb, tp[None], tt[None])
    diffs["one frame"] = max(check("vertices", posed.vertices, v[0]),
                             check("joints", posed.joints, j[0]))
    (dv_db, dv_dp, dv_dt), (dj_db, dj_dp, dj_dt) = jacobian(tb, tp, tt)
    diffs["Jacobians"] = max(
        check("d vertices/d betas", posed.vertices_betas, dv_db),
        check("d vertices/d pose", posed.vertices_pose, dv_dp),
        check("d vertices/d trans", posed.vertices_trans, dv_dt),
        check("d joints/d betas", posed.joints_betas, dj_db),
        check("d joints/d pose", posed.joints_pose, dj_dp),
        check("d joints/d trans", posed.joints_trans, dj_dt))
    batch = flsh.pose_body_batch(model, betas, poses, transes)
    with torch.no_grad():
        vb, jb, _, _ = reference.forward(tb, tposes, ttranses)
    diffs["batch"] = max(check("batch vertices", batch.vertices, vb),
                         check("batch joints", batch.joints, jb))

    def torch_frame():
        with torch.no_grad():
            reference.forward(tb, tp[None], tt[None])

    def torch_batch():
        with torch.no_grad():
            reference.forward(tb, tposes, ttranses)

    rows = [
        ("one frame", median_ms(lambda: flsh.pose_body(model, betas, pose, trans), repeats),
         median_ms(torch_frame, repeats), diffs["one frame"]),
        ("one frame + Jacobians",
         median_ms(lambda: flsh.pose_body(model, betas, pose, trans, jacobians=True), repeats),
         median_ms(lambda: jacobian(tb, tp, tt), max(3, repeats // 4)), diffs["Jacobians"]),
        (f"batch of {BATCH_FRAMES}, per frame",
         median_ms(lambda: flsh.pose_body_batch(model, betas, poses, transes), repeats)
         / BATCH_FRAMES,
         median_ms(torch_batch, max(3, repeats // 2)) / BATCH_FRAMES, diffs["batch"]),
    ]
    return [(label,) + row for row in rows]


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=20, help="minimum timed runs per case")
    parser.add_argument("--vertices", type=int, default=6890, help="synthetic body size")
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1,
                        help="threads for flsh (OpenMP) and torch")
    args = parser.parse_args()

    global flsh, torch, smpl_torch
    threads = args.threads
    os.environ["OMP_NUM_THREADS"] = str(threads)
    import torch
    import flsh
    from flsh import smpl_torch
    torch.set_num_threads(threads)
    rng = np.random.default_rng(2024)
    body = flsh.make_synthetic_body(vertices=args.vertices)
    print(f"flsh {flsh.__version__}, torch {torch.__version__}, {threads} threads each, "
          f"numpy {np.__version__}; V = {body.num_vertices}, K = {body.num_betas}, float64, CPU")

    results = []
    with tempfile.TemporaryDirectory() as directory:
        dense = dense_posedirs_model(body, directory)
        for label, model in (("synthetic", body), ("dense posedirs", dense)):
            results += run_model(label, model, args.repeats, rng)

    header = (f"{'model':<16} {'case':<26} {'flsh ms':>10} {'torch ms':>10} "
              f"{'speed-up':>9} {'max |diff|':>11}")
    print(header)
    print("-" * len(header))
    for label, case, flsh_ms, torch_ms, diff in results:
        print(f"{label:<16} {case:<26} {flsh_ms:>10.3f} {torch_ms:>10.3f} "
              f"{torch_ms / flsh_ms:>8.1f}x {diff:>11.1e}")


if __name__ == "__main__":
    main()
