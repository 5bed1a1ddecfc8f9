"""AMASS clips and SMPL-H model files through the Python API (issue 27): z-up clips turned into
flsh's y-up world, the ground under a clip, betas cut with a warning, SMPL-H files read as SMPL
with the fingers merged into the hands."""
import numpy as np
import pytest

import flsh

Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # file z up -> world y up


def rotation(v):
    """Rodrigues' formula for one rotation vector."""
    angle = np.linalg.norm(v)
    if angle < 1e-300:
        return np.eye(3)
    k = v / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def amass_file(path, world_motion, gender="female"):
    """`world_motion` (y up) stored as AMASS does: z up, 156 pose values, 16 betas, no `up`."""
    stored = flsh.rotate_motion(world_motion, Z_UP.T)
    T = stored.num_frames
    poses = np.zeros((T, 156))
    poses[:, :72] = stored.poses
    np.savez(path, poses=poses, trans=stored.trans, betas=np.linspace(-0.5, 0.5, 16),
             mocap_framerate=np.array(120.0), gender=np.array(gender))
    return path


def test_up_axis_rotation():
    np.testing.assert_array_equal(flsh.world_from_up_axis("z"), Z_UP)
    np.testing.assert_array_equal(flsh.world_from_up_axis("y"), np.eye(3))
    with pytest.raises(ValueError, match='expected "y" or "z"'):
        flsh.world_from_up_axis("x")


def test_amass_clip_is_read_z_up_and_turned_upright(tmp_path, capfd):
    walk = flsh.make_builtin_motion("walk", seconds=0.5, fps=30.0)
    path = amass_file(tmp_path / "clip.npz", walk)
    raw = np.load(path)
    assert np.abs(raw["trans"] - walk.trans).max() > 0.1  # stored z up

    motion = flsh.load_motion(path)
    assert motion.up == "z"
    np.testing.assert_allclose(motion.trans, walk.trans, atol=1e-12)
    for t in range(motion.num_frames):
        np.testing.assert_allclose(rotation(motion.poses[t, :3]), rotation(walk.poses[t, :3]),
                                   atol=1e-12)
    assert "not upright" not in capfd.readouterr().err
    assert flsh.upright_warning(motion) == ""

    # Read as y up it lies on its back: a warning on stderr and from upright_warning.
    lying = flsh.load_motion(path, up="y")
    assert lying.up == "y"
    np.testing.assert_array_equal(lying.trans, raw["trans"])
    assert "the body is not upright at frame 0" in capfd.readouterr().err
    assert 'up="z" in Python' in flsh.upright_warning(lying)

    # The same arrays in memory, and saved z up, come back the same.
    in_memory = flsh.Motion(raw["poses"], raw["trans"], fps=120.0, up="z")
    np.testing.assert_allclose(in_memory.trans, motion.trans, atol=1e-15)
    flsh.save_motion(motion, tmp_path / "again.npz", up="z")
    assert str(np.load(tmp_path / "again.npz")["up"]) == "z"
    np.testing.assert_allclose(flsh.load_motion(tmp_path / "again.npz").trans, walk.trans,
                               atol=1e-12)


def test_rotated_body_turns_about_the_rest_root_joint(body, rng):
    walk = flsh.make_builtin_motion("jumping_jacks", seconds=0.2, fps=30.0)
    R = rotation(np.array([0.3, -0.8, 0.4]))
    turned = flsh.rotate_motion(walk, R)
    betas = rng.normal(0.0, 1.0, body.num_betas)
    before = flsh.pose_body_batch(body, betas, walk.poses, walk.trans).vertices
    after = flsh.pose_body_batch(body, betas, turned.poses, turned.trans).vertices
    J0 = flsh.pose_body(body, betas, np.zeros(72)).rest_joints[0]
    expected = (before.reshape(len(before), -1, 3) - J0) @ R.T + J0
    assert np.abs(after - before).max() > 0.1
    np.testing.assert_allclose(after.reshape(expected.shape), expected, atol=1e-12)
    with pytest.raises(ValueError, match="rotation matrix"):
        flsh.rotate_motion(walk, np.diag([1.0, 1.0, -1.0]))


def test_ground_under_a_clip_is_its_lowest_posed_vertex(body):
    motion = flsh.placed_motion(flsh.make_builtin_motion("jump", seconds=1.0, fps=20.0),
                                offset=(0.0, 0.7, 0.0))
    betas = np.zeros(body.num_betas)
    posed = flsh.pose_body_batch(body, betas, motion.poses, motion.trans).vertices
    lowest = posed.reshape(len(posed), -1, 3)[..., 1]
    assert flsh.lowest_point_height(body, betas, motion, seconds=0.0) == lowest[0].min()
    assert flsh.lowest_point_height(body, betas, motion, seconds=0.5) == lowest[:11].min()
    assert flsh.lowest_point_height(body, None, motion, seconds=99.0) == lowest.min()


def test_fit_betas_cuts_to_the_model_and_warns_once(body):
    sixteen = np.linspace(-1.0, 1.0, 16)
    with pytest.warns(UserWarning, match="clip.npz has 16 shape coefficients, the model 10"):
        fitted = flsh.fit_betas(sixteen, body, origin="clip.npz")
    np.testing.assert_array_equal(fitted, sixteen[:10])
    padded = np.concatenate([sixteen[:10], np.zeros(6)])
    np.testing.assert_array_equal(flsh.fit_betas(padded, body), sixteen[:10])  # no warning


def test_smplh_model_file_loads_as_smpl_with_merged_hands(body, tmp_path, rng):
    """An SMPL-H file made from the synthetic body (fingers splitting each hand's weight) poses
    exactly like the body for poses with the hands at rest."""
    V = body.num_vertices
    parents = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19]
    for wrist in (20, 21):
        for _ in range(5):
            parents += [wrist, len(parents), len(parents) + 1]
    weights = np.zeros((V, 52))
    weights[:, :22] = body.weights[:, :22]
    regressor = np.zeros((52, V))
    regressor[:22] = body.J_regressor[:22]
    for hand in (0, 1):
        first = 22 + 15 * hand
        weights[:, first + 3] += 0.6 * body.weights[:, 22 + hand]  # middle1
        weights[:, first + 9] += 0.4 * body.weights[:, 22 + hand]  # ring1
        regressor[first:first + 15] = body.J_regressor[22 + hand]
    posedirs = np.concatenate([body.posedirs[..., :189], rng.normal(0, 1e-3, (V, 3, 270))], -1)
    shapedirs = np.concatenate([body.shapedirs, rng.normal(0, 1e-3, (V, 3, 6))], -1)
    np.savez(tmp_path / "smplh.npz", v_template=body.v_template, shapedirs=shapedirs,
             posedirs=posedirs, J_regressor=regressor, weights=weights,
             kintree_table=np.stack([parents, np.arange(52)]), f=body.faces,
             hands_componentsl=np.zeros((45, 45)))  # an extra key, as in AMASS's files
    smplh = flsh.load_body_model(tmp_path / "smplh.npz")
    assert smplh.family == "SMPL-H" and body.family == "SMPL"
    assert smplh.num_joints == 24 and smplh.num_betas == body.num_betas + 6
    pose = rng.normal(0.0, 0.4, 72)
    pose[66:] = 0.0
    betas = rng.normal(0.0, 1.0, body.num_betas)
    a = flsh.pose_body(smplh, np.concatenate([betas, np.zeros(6)]), pose)
    b = flsh.pose_body(body, betas, pose)
    np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-12)

    kintree = np.stack([parents[:24] + [20] * 31, np.arange(55)])
    np.savez(tmp_path / "smplx.npz", kintree_table=kintree, v_template=body.v_template)
    with pytest.raises(ValueError, match=r"kintree_table' has shape \(2, 55\): 55 joints \(SMPL-X\?\)"):
        flsh.load_body_model(tmp_path / "smplx.npz")
