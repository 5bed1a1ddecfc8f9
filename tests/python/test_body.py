"""flsh.pose_body / pose_body_batch against the plain-PyTorch SMPL reference, the body model's
arrays and files, the rotation helpers, and the input checks of the bindings."""
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

import flsh
from flsh import smpl_torch


def random_pose(rng, scale=0.4, size=72):
    """Axis-angle pose, rad: each component a few tenths of a radian."""
    return rng.normal(0.0, scale, size)


def reference_frame(reference, betas, pose, trans):
    v, j, G, J = reference.forward(betas, pose[None], trans[None])
    return v[0].numpy(), j[0].numpy(), G[0].numpy(), J[0].numpy()


# --- forward pass --------------------------------------------------------------------------


def test_pose_body_matches_torch_reference(body, reference, rng):
    for _ in range(4):
        betas = rng.normal(0.0, 1.0, body.num_betas)
        pose = random_pose(rng)
        trans = rng.normal(0.0, 0.5, 3)
        posed = flsh.pose_body(body, betas, pose, trans)
        v, j, G, J = reference_frame(reference, betas, pose, trans)
        assert posed.vertices.shape == (body.num_vertices, 3)
        assert posed.joints.shape == (24, 3)
        assert posed.transforms.shape == (24, 4, 4)
        # The pose moves the body: the comparison is not between two rest poses.
        assert np.abs(posed.vertices - flsh.shaped_vertices(body, betas)).max() > 0.05
        np.testing.assert_allclose(posed.vertices, v, rtol=0, atol=1e-10)
        np.testing.assert_allclose(posed.joints, j, rtol=0, atol=1e-10)
        np.testing.assert_allclose(posed.rest_joints, J, rtol=0, atol=1e-10)
        np.testing.assert_allclose(posed.transforms, G, rtol=0, atol=1e-10)


def test_zero_pose_is_the_shaped_template(body, rng):
    betas = rng.normal(0.0, 1.0, body.num_betas)
    posed = flsh.pose_body(body, betas, np.zeros(72))
    np.testing.assert_allclose(posed.vertices, flsh.shaped_vertices(body, betas), atol=1e-12)
    np.testing.assert_allclose(posed.joints, posed.rest_joints, atol=1e-12)


def test_short_betas_are_zero_padded(body, rng):
    pose = random_pose(rng)
    betas = rng.normal(0.0, 1.0, 3)
    padded = np.concatenate([betas, np.zeros(body.num_betas - 3)])
    np.testing.assert_array_equal(flsh.pose_body(body, betas, pose).vertices,
                                  flsh.pose_body(body, padded, pose).vertices)


def test_smplh_pose_uses_body_joints_only(body, rng):
    pose156 = random_pose(rng, size=156)
    pose72 = np.concatenate([pose156[:66], np.zeros(6)])
    np.testing.assert_array_equal(flsh.to_smpl_pose(pose156), pose72)
    betas = np.zeros(body.num_betas)
    np.testing.assert_allclose(flsh.pose_body(body, betas, pose156).vertices,
                               flsh.pose_body(body, betas, pose72).vertices, atol=1e-14)


def test_batch_matches_single_frames(body, rng):
    T = 6
    betas = rng.normal(0.0, 1.0, body.num_betas)
    poses = np.stack([random_pose(rng) for _ in range(T)])
    trans = rng.normal(0.0, 0.5, (T, 3))
    batch = flsh.pose_body_batch(body, betas, poses, trans)
    assert batch.vertices.shape == (T, body.num_vertices, 3)
    assert batch.joints.shape == (T, 24, 3)
    for t in range(T):
        single = flsh.pose_body(body, betas, poses[t], trans[t])
        np.testing.assert_allclose(batch.vertices[t], single.vertices, rtol=0, atol=1e-12)
        np.testing.assert_allclose(batch.joints[t], single.joints, rtol=0, atol=1e-12)
    without_trans = flsh.pose_body_batch(body, betas, poses)
    np.testing.assert_allclose(without_trans.vertices + trans[:, None, :], batch.vertices,
                               atol=1e-12)


def test_batch_matches_torch_reference(body, reference, rng):
    T = 4
    betas = rng.normal(0.0, 1.0, body.num_betas)
    poses = np.stack([random_pose(rng, size=156) for _ in range(T)])
    trans = rng.normal(0.0, 0.5, (T, 3))
    batch = flsh.pose_body_batch(body, betas, poses, trans)
    v, j, _, _ = reference.forward(betas, poses, trans)
    np.testing.assert_allclose(batch.vertices, v.numpy(), rtol=0, atol=1e-10)
    np.testing.assert_allclose(batch.joints, j.numpy(), rtol=0, atol=1e-10)


def test_jacobians_match_torch_autograd(body, reference, rng):
    betas = rng.normal(0.0, 1.0, body.num_betas)
    pose = random_pose(rng)
    trans = rng.normal(0.0, 0.5, 3)
    posed = flsh.pose_body(body, betas, pose, trans, jacobians=True)

    def frame(b, p, t):
        v, j, _, _ = reference.forward(b, p[None], t[None])
        return v[0], j[0]

    inputs = tuple(torch.tensor(a) for a in (betas, pose, trans))
    (dv_db, dv_dp, dv_dt), (dj_db, dj_dp, dj_dt) = torch.autograd.functional.jacobian(
        frame, inputs, vectorize=True, strategy="forward-mode")
    V, K = body.num_vertices, body.num_betas
    pairs = [
        (posed.vertices_betas, dv_db, (V, 3, K)),
        (posed.vertices_pose, dv_dp, (V, 3, 72)),
        (posed.vertices_trans, dv_dt, (V, 3, 3)),
        (posed.joints_betas, dj_db, (24, 3, K)),
        (posed.joints_pose, dj_dp, (24, 3, 72)),
        (posed.joints_trans, dj_dt, (24, 3, 3)),
    ]
    for analytic, autograd, shape in pairs:
        assert analytic.shape == shape
        assert np.abs(analytic).max() > 1e-3  # a zero Jacobian would match nothing
        np.testing.assert_allclose(analytic, autograd.numpy(), rtol=0, atol=1e-9)
    # Asking for Jacobians does not change the pose itself.
    plain = flsh.pose_body(body, betas, pose, trans)
    np.testing.assert_array_equal(plain.vertices, posed.vertices)
    assert plain.vertices_pose is None


# --- the model's arrays and files ----------------------------------------------------------


def test_body_model_arrays(body):
    V, K = body.num_vertices, body.num_betas
    assert (V, body.num_faces, body.num_joints) == (800, 2 * 800 - 4, 24)
    assert body.v_template.shape == (V, 3)
    assert body.shapedirs.shape == (V, 3, K)
    assert body.posedirs.shape == (V, 3, 207)
    assert body.J_regressor.shape == (24, V)
    assert body.weights.shape == (V, 24)
    assert body.faces.shape == (body.num_faces, 3) and body.faces.dtype.kind == "i"
    assert body.faces.min() == 0 and body.faces.max() == V - 1
    assert tuple(body.parents) == flsh.SMPL_PARENTS
    np.testing.assert_allclose(body.weights.sum(axis=1), 1.0, atol=1e-9)
    assert len(flsh.SMPL_JOINT_NAMES) == 24 and flsh.SMPL_JOINT_NAMES[0] == "pelvis"
    assert flsh.smpl_joint_index("pelvis") == 0
    with pytest.raises(ValueError, match="nose"):
        flsh.smpl_joint_index("nose")
    # The model is immutable: its arrays are read-only views.
    with pytest.raises(ValueError, match="read-only"):
        body.v_template[0, 0] = 1.0


def test_shapedirs_layout_matches_shaped_vertices(body, rng):
    betas = rng.normal(0.0, 1.0, body.num_betas)
    expected = body.v_template + np.einsum("vck,k->vc", body.shapedirs, betas)
    np.testing.assert_allclose(flsh.shaped_vertices(body, betas), expected, atol=1e-12)


def test_save_load_round_trip(body, tmp_path, rng):
    path = tmp_path / "model.npz"
    flsh.save_body_model(body, path)  # os.PathLike accepted
    loaded = flsh.load_body_model(str(path))
    for name in ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "parents",
                 "faces"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(body, name), err_msg=name)
    betas, pose = rng.normal(0.0, 1.0, body.num_betas), random_pose(rng)
    np.testing.assert_array_equal(flsh.pose_body(loaded, betas, pose).vertices,
                                  flsh.pose_body(body, betas, pose).vertices)
    assert str(path) in loaded.source


def test_synthetic_body_is_deterministic_and_checked():
    a = flsh.make_synthetic_body(flsh.SyntheticBodyOptions(vertices=300, height=1.5))
    b = flsh.make_synthetic_body(vertices=300, height=1.5)
    np.testing.assert_array_equal(a.v_template, b.v_template)
    height = a.v_template[:, 1].max() - a.v_template[:, 1].min()
    assert abs(height - 1.5) < 0.1
    with pytest.raises(ValueError, match="200"):
        flsh.make_synthetic_body(vertices=100)


# --- rotations -----------------------------------------------------------------------------


def test_rodrigues_and_log_match_scipy(rng):
    for theta in [rng.normal(0.0, 1.0, 3), np.zeros(3), np.array([0.0, 0.0, np.pi - 1e-9])]:
        R = flsh.rodrigues(theta)
        np.testing.assert_allclose(R, Rotation.from_rotvec(theta).as_matrix(), atol=1e-12)
        back = flsh.log_so3(R)
        np.testing.assert_allclose(flsh.rodrigues(back), R, atol=1e-9)
    with pytest.raises(ValueError, match="rotation matrix"):
        flsh.log_so3(2.0 * np.eye(3))
    np.testing.assert_allclose(smpl_torch.batch_rodrigues(torch.tensor(theta)).numpy(),
                               flsh.rodrigues(theta), atol=1e-12)


# --- input checks --------------------------------------------------------------------------


def test_wrong_pose_length_names_the_shapes(body):
    betas = np.zeros(body.num_betas)
    with pytest.raises(ValueError, match=re.escape("pose: expected shape (72,) or (156,), got (70,)")):
        flsh.pose_body(body, betas, np.zeros(70))
    with pytest.raises(ValueError, match=re.escape("got (1, 72)")):
        flsh.pose_body(body, betas, np.zeros((1, 72)))
    with pytest.raises(ValueError, match=re.escape("poses: expected shape (T, 72) or (T, 156), got (5, 70)")):
        flsh.pose_body_batch(body, betas, np.zeros((5, 70)))
    with pytest.raises(ValueError, match=re.escape("trans: expected shape (5, 3), got (4, 3)")):
        flsh.pose_body_batch(body, betas, np.zeros((5, 72)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match=re.escape("trans: expected shape (3,), got (2,)")):
        flsh.pose_body(body, betas, np.zeros(72), np.zeros(2))
    with pytest.raises(ValueError, match="betas: expected at most"):
        flsh.pose_body(body, np.zeros(body.num_betas + 1), np.zeros(72))


def test_bad_values_and_dtypes_are_refused(body, tmp_path):
    betas = np.zeros(body.num_betas)
    pose = np.zeros(72)
    pose[5] = np.nan
    with pytest.raises(ValueError, match="pose: contains NaN"):
        flsh.pose_body(body, betas, pose)
    with pytest.raises(ValueError, match="dtype complex128"):
        flsh.pose_body(body, betas, np.zeros(72, dtype=complex))
    with pytest.raises(ValueError, match="dtype object"):
        flsh.pose_body(body, betas, np.array([None] * 72))
    with pytest.raises(ValueError, match="pose: expected a float or integer array"):
        flsh.pose_body(body, betas, "x" * 72)
    with pytest.raises(ValueError, match=re.escape("vertices: expected shape (N, 3), got (800, 2)")):
        flsh.write_ply(tmp_path / "bad.ply", np.zeros((800, 2)), body.faces)
    with pytest.raises(ValueError, match="faces: expected an integer array"):
        flsh.write_ply(tmp_path / "bad.ply", body.v_template, body.faces.astype(float))
    assert not (tmp_path / "bad.ply").exists()


def test_absurd_finite_values_are_refused_naming_the_argument(body):
    # Issue 23: a pose value of 1e300 returned all-NaN vertices without an error.
    betas = np.zeros(body.num_betas)
    pose = np.zeros(72)
    pose[3 * 5 + 1] = 1e300
    with pytest.raises(ValueError, match=re.escape("joint 5 (right_knee) has angle |θ| = 1e+300 rad, "
                                                   "expected at most 1e6 rad")):
        flsh.pose_body(body, betas, pose)
    poses = np.zeros((4, 72))
    poses[2, 0] = -1e7
    with pytest.raises(ValueError, match="frame 2: joint 0"):
        flsh.pose_body_batch(body, betas, poses)
    big_betas = betas.copy()
    big_betas[1] = 1e300
    with pytest.raises(ValueError, match=re.escape("betas[1] = 1e+300, expected within [-100, 100]")):
        flsh.pose_body(body, big_betas, np.zeros(72))
    # Large angles within the bound are rotations like any other (the angle modulo 2π).
    pose = np.zeros(72)
    pose[3 * 4 + 1] = 0.5
    wound = pose.copy()
    wound[3 * 4 + 1] += 2 * np.pi * 1000
    np.testing.assert_allclose(flsh.pose_body(body, betas, wound).vertices,
                               flsh.pose_body(body, betas, pose).vertices, atol=1e-10)


def test_rodrigues_of_huge_finite_angles_is_a_rotation():
    for angle in (1e6, 1e155, 1e300):
        axis = np.array([0.6, 0.0, 0.8])
        R = flsh.rodrigues(angle * axis)
        assert np.isfinite(R).all(), angle
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
        if angle <= 1e6:  # beyond, one ulp of the angle is more than a turn
            np.testing.assert_allclose(np.trace(R), 1 + 2 * np.cos(angle), atol=1e-9)
        np.testing.assert_allclose(R @ axis, axis, atol=1e-13)
    with pytest.raises(ValueError, match="theta"):
        flsh.rodrigues([np.inf, 0.0, 0.0])


def test_body_model_with_absurd_values_names_the_file_and_key(body, tmp_path):
    # Issue 23: a joint-regressor entry of 1e300 crashed the FEM set-up.
    path = tmp_path / "body.npz"
    flsh.save_body_model(body, path)
    arrays = dict(np.load(path))
    arrays["J_regressor"] = arrays["J_regressor"].copy()
    arrays["J_regressor"][3, 17] = 1e300
    bad = tmp_path / "bad.npz"
    np.savez(bad, **arrays)
    with pytest.raises(ValueError, match=re.escape(
            "bad.npz: array 'J_regressor': entry [3, 17] = 1e+300 is outside [-1000, 1000]")):
        flsh.load_body_model(bad)


def test_float32_and_integer_inputs_are_accepted(body, rng):
    betas = rng.normal(0.0, 1.0, body.num_betas).astype(np.float32)
    pose = random_pose(rng).astype(np.float32)
    expected = flsh.pose_body(body, betas.astype(np.float64), pose.astype(np.float64)).vertices
    np.testing.assert_array_equal(flsh.pose_body(body, betas, pose).vertices, expected)
    np.testing.assert_array_equal(flsh.pose_body(body, [0] * 10, np.zeros(72, dtype=np.int32)).vertices,
                                  flsh.pose_body(body, np.zeros(10), np.zeros(72)).vertices)
    # Non-contiguous views are fine too.
    poses = np.zeros((3, 144))[:, ::2]
    assert flsh.pose_body_batch(body, betas, poses).vertices.shape == (3, body.num_vertices, 3)


def test_missing_and_corrupt_model_files(tmp_path):
    missing = tmp_path / "no_such_model.npz"
    with pytest.raises(FileNotFoundError, match="no_such_model.npz"):
        flsh.load_body_model(missing)
    blocker = tmp_path / "a_file"
    blocker.write_text("a file where a directory is needed")
    with pytest.raises(OSError, match="a_file"):
        flsh.save_body_model(flsh.make_synthetic_body(vertices=200), blocker / "model.npz")
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"this is not a zip archive")
    with pytest.raises(ValueError, match="garbage.npz"):
        flsh.load_body_model(garbage)


def test_version_matches_cmake_project():
    cmake = (Path(__file__).resolve().parents[2] / "CMakeLists.txt").read_text()
    version = re.search(r"project\(flsh VERSION ([0-9.]+)", cmake).group(1)
    assert flsh.__version__ == version
    public = {name for name in dir(flsh._flsh) if not name.startswith("_")}
    assert public <= set(flsh.__all__), public - set(flsh.__all__)
    namespace = {}
    exec("from flsh import *", namespace)
    assert "pose_body" in namespace and "__version__" in namespace
