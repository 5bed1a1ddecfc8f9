"""Motions, meshes and pictures through the Python API: round trips and input checks."""
import os
import re

import numpy as np
import pytest

import flsh


def test_motion_round_trip(tmp_path, rng):
    T = 12
    motion = flsh.Motion(rng.normal(0.0, 0.3, (T, 72)), rng.normal(0.0, 1.0, (T, 3)),
                         betas=rng.normal(0.0, 1.0, 16), fps=60.0, gender="female")
    assert motion.num_frames == len(motion) == T
    assert motion.duration == pytest.approx((T - 1) / 60.0)
    path = tmp_path / "motion.npz"
    flsh.save_motion(motion, path)
    loaded = flsh.load_motion(path)
    np.testing.assert_array_equal(loaded.poses, motion.poses)
    np.testing.assert_array_equal(loaded.trans, motion.trans)
    np.testing.assert_array_equal(loaded.betas, motion.betas)
    assert loaded.fps == 60.0
    assert loaded.gender == "female"
    assert str(path) in loaded.source


def test_motion_from_smplh_poses_keeps_body_joints(rng):
    poses = rng.normal(0.0, 0.3, (5, 156))
    motion = flsh.Motion(poses)
    assert motion.poses.shape == (5, 72)
    np.testing.assert_array_equal(motion.poses[:, :66], poses[:, :66])
    np.testing.assert_array_equal(motion.poses[:, 66:], 0.0)
    np.testing.assert_array_equal(motion.trans, np.zeros((5, 3)))
    assert motion.betas.shape == (0,)


def test_motion_checks_its_arrays():
    with pytest.raises(ValueError, match=re.escape("trans: expected shape (4, 3), got (5, 3)")):
        flsh.Motion(np.zeros((4, 72)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match=re.escape("got (4, 70)")):
        flsh.Motion(np.zeros((4, 70)))
    with pytest.raises(ValueError, match="fps"):
        flsh.Motion(np.zeros((4, 72)), fps=0.0)
    with pytest.raises(ValueError, match="NaN"):
        flsh.Motion(np.full((4, 72), np.nan))


def test_builtin_motions(body):
    names = flsh.builtin_motion_names()
    assert "walk" in names and len(names) >= 3
    resting = []
    for name in names:
        motion = flsh.make_builtin_motion(name, seconds=1.0, fps=30.0)
        assert motion.poses.ndim == 2 and motion.poses.shape[1] == 72, name
        assert 30 <= motion.num_frames <= 31, name
        assert motion.trans.shape == (motion.num_frames, 3)
        assert np.isfinite(motion.poses).all() and np.isfinite(motion.trans).all()
        if np.ptp(motion.poses, axis=0).max() < 0.1:
            resting.append(name)
        assert motion.source == "builtin:" + name
        posed = flsh.pose_body_batch(body, np.zeros(body.num_betas), motion.poses, motion.trans)
        assert np.isfinite(posed.vertices).all()
    # Static motions ("stand", "t_pose") exist, but most motions, walking above all, move.
    assert "walk" not in resting and len(resting) <= len(names) // 2, resting
    assert flsh.load_or_make_motion("builtin:walk", 1.0, 30.0).num_frames == \
        flsh.make_builtin_motion("walk", 1.0, 30.0).num_frames
    with pytest.raises(ValueError, match="moonwalk"):
        flsh.make_builtin_motion("moonwalk")


@pytest.mark.parametrize("reader", [flsh.load_motion, flsh.read_mesh, flsh.read_png])
def test_missing_files_raise_file_not_found(tmp_path, reader):
    with pytest.raises(FileNotFoundError, match="absent.file"):
        reader(tmp_path / "absent.file")


@pytest.mark.parametrize("name,kwargs", [("mesh.ply", {}), ("ascii.ply", {"binary": False}),
                                         ("mesh.obj", None)])
def test_mesh_write_read(body, tmp_path, rng, name, kwargs):
    V = flsh.pose_body(body, np.zeros(body.num_betas), rng.normal(0.0, 0.3, 72)).vertices
    path = tmp_path / name
    if kwargs is None:
        flsh.write_obj(path, V, body.faces)
    else:
        flsh.write_ply(path, V, body.faces, **kwargs)
    V2, F2 = flsh.read_mesh(path)
    assert V2.shape == V.shape and V2.dtype == np.float64
    np.testing.assert_allclose(V2, V, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(F2, body.faces)


def test_ply_with_colors(body, tmp_path):
    colors = np.clip(body.weights[:, :3] * 3.0, 0.0, 1.0)
    path = tmp_path / "colored.ply"
    flsh.write_ply(path, body.v_template, body.faces, colors=colors)
    V, F = flsh.read_mesh(path)
    np.testing.assert_allclose(V, body.v_template, atol=1e-6)
    with pytest.raises(ValueError, match=re.escape("colors: expected shape (800, 3), got (799, 3)")):
        flsh.write_ply(tmp_path / "bad.ply", body.v_template, body.faces, colors=colors[1:])


def test_render_to_png_and_back(body, tmp_path):
    options = flsh.RenderOptions(width=120, height=160)
    image = flsh.render_mesh(body.v_template, body.faces, options)
    assert (image.width, image.height) == (120, 160)
    pixels = image.array
    assert pixels.shape == (160, 120, 3) and pixels.dtype == np.uint8
    background = np.all(pixels == 255, axis=2)
    assert 0.02 < 1.0 - background.mean() < 0.98  # the body covers part of the picture
    path = tmp_path / "body.png"
    flsh.write_png(path, image)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    np.testing.assert_array_equal(flsh.read_png(path).array, pixels)
    # A numpy array is accepted too, uint8 only.
    flsh.write_png(tmp_path / "copy.png", pixels)
    np.testing.assert_array_equal(flsh.read_png(tmp_path / "copy.png").array, pixels)
    with pytest.raises(ValueError, match="uint8"):
        flsh.write_png(tmp_path / "float.png", pixels / 255.0)


def test_render_sheet(body):
    motion = flsh.make_builtin_motion("walk", seconds=0.5, fps=6.0)
    frames = flsh.pose_body_batch(body, np.zeros(body.num_betas), motion.poses[:3],
                                  motion.trans[:3]).vertices
    options = flsh.RenderOptions(width=80, height=100)
    sheet = flsh.render_sheet(frames, body.faces, options)
    assert sheet.array.shape == (sheet.height, sheet.width, 3)
    assert sheet.width > options.width  # the three frames side by side
    assert (sheet.array != 255).any()
    with pytest.raises(ValueError, match=re.escape("frames: expected shape (N, V, 3)")):
        flsh.render_sheet(frames[0], body.faces, options)


def test_render_options_are_checked():
    options = flsh.RenderOptions(frame=[[-1, 0, -1], [1, 2, 1]], background=[0.0, 0.0, 0.0])
    np.testing.assert_array_equal(options.frame, [[-1, 0, -1], [1, 2, 1]])
    assert flsh.RenderOptions().frame is None
    with pytest.raises(ValueError, match="width"):
        flsh.RenderOptions(width=0)
    with pytest.raises(ValueError, match=re.escape("frame: expected shape (2, 3), got (3,)")):
        flsh.RenderOptions(frame=[0.0, 1.0, 2.0])
    with pytest.raises(ValueError, match="base_color"):
        flsh.RenderOptions(base_color=[0.0, 2.0, 0.0])


def test_hostile_input_files_raise_clean_errors(tmp_path):
    # 200 000 nested '[' overflowed the stack of the scene reader (issue 23): now a ValueError
    # naming the file, raised before the JSON is parsed.
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 200000 + "]" * 200000)
    with pytest.raises(ValueError, match=re.escape(str(deep)) + ".*nested deeper than 64"):
        flsh.load_scene_file(deep)
    # A FIFO at an input path is refused without opening it (an open would block forever).
    fifo = tmp_path / "motion.npz"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match="is a FIFO"):
        flsh.load_motion(fifo)
    with pytest.raises(ValueError, match="is a FIFO"):
        flsh.load_scene_file(fifo)
