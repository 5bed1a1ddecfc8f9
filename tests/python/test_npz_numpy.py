"""flsh's .npz files and numpy's: files flsh writes load in numpy with the documented dtypes and
shapes, and files numpy writes (float32, uint32 tables, compressed, Fortran order, SMPL-H
motions) load in flsh."""
import numpy as np
import pytest

import flsh


def smpl_style_arrays(body, dtype=np.float32):
    """The body's arrays as an SMPL release stores them: float32, uint32 tables whose root
    parent is 2³²−1."""
    kintree = np.stack([body.parents, np.arange(24)]).astype(np.int64)
    kintree[kintree < 0] = 2**32 - 1
    return {
        "v_template": body.v_template.astype(dtype),
        "shapedirs": body.shapedirs.astype(dtype),
        "posedirs": body.posedirs.astype(dtype),
        "J_regressor": body.J_regressor.astype(dtype),
        "weights": body.weights.astype(dtype),
        "kintree_table": kintree.astype(np.uint32),
        "f": body.faces.astype(np.uint32),
    }


def test_saved_model_loads_in_numpy(body, tmp_path):
    path = tmp_path / "model.npz"
    flsh.save_body_model(body, path)
    V, K = body.num_vertices, body.num_betas
    with np.load(path) as npz:
        expected = {
            "v_template": ((V, 3), np.float64), "shapedirs": ((V, 3, K), np.float64),
            "posedirs": ((V, 3, 207), np.float64), "J_regressor": ((24, V), np.float64),
            "weights": ((V, 24), np.float64), "kintree_table": ((2, 24), np.int64),
            "f": ((body.num_faces, 3), np.int64),
        }
        for key, (shape, dtype) in expected.items():
            assert npz[key].shape == shape, key
            assert npz[key].dtype == dtype, key
        np.testing.assert_array_equal(npz["v_template"], body.v_template)
        np.testing.assert_array_equal(npz["shapedirs"], body.shapedirs)
        np.testing.assert_array_equal(npz["posedirs"], body.posedirs)
        np.testing.assert_array_equal(npz["J_regressor"], body.J_regressor)
        np.testing.assert_array_equal(npz["kintree_table"][0], body.parents)
        np.testing.assert_array_equal(npz["kintree_table"][1], np.arange(24))
        np.testing.assert_array_equal(npz["f"], body.faces)


def test_saved_motion_loads_in_numpy(tmp_path, rng):
    motion = flsh.Motion(rng.normal(0.0, 0.3, (7, 72)), rng.normal(0.0, 1.0, (7, 3)),
                         betas=rng.normal(0.0, 1.0, 10), fps=120.0, gender="male")
    path = tmp_path / "motion.npz"
    flsh.save_motion(motion, path)
    with np.load(path) as npz:
        assert npz["poses"].shape == (7, 72) and npz["poses"].dtype == np.float64
        assert npz["trans"].shape == (7, 3) and npz["trans"].dtype == np.float64
        np.testing.assert_array_equal(npz["poses"], motion.poses)
        np.testing.assert_array_equal(npz["trans"], motion.trans)
        np.testing.assert_array_equal(npz["betas"], motion.betas)
        assert float(npz["mocap_framerate"]) == 120.0
        assert str(npz["gender"]) == "male"


@pytest.mark.parametrize("writer", [np.savez, np.savez_compressed])
def test_numpy_float32_model_loads_in_flsh(body, tmp_path, rng, writer):
    arrays = smpl_style_arrays(body)
    path = tmp_path / "smpl_float32.npz"
    writer(path, **arrays)
    model = flsh.load_body_model(path)
    assert model.num_vertices == body.num_vertices and model.num_betas == body.num_betas
    np.testing.assert_array_equal(model.v_template, arrays["v_template"].astype(np.float64))
    np.testing.assert_array_equal(model.shapedirs, arrays["shapedirs"].astype(np.float64))
    np.testing.assert_array_equal(model.posedirs, arrays["posedirs"].astype(np.float64))
    np.testing.assert_array_equal(model.J_regressor, arrays["J_regressor"].astype(np.float64))
    np.testing.assert_array_equal(model.faces, body.faces)
    assert tuple(model.parents) == flsh.SMPL_PARENTS
    # float32 rounding moves vertices by far less than a micrometre.
    betas, pose = rng.normal(0.0, 1.0, body.num_betas), rng.normal(0.0, 0.4, 72)
    np.testing.assert_allclose(flsh.pose_body(model, betas, pose).vertices,
                               flsh.pose_body(body, betas, pose).vertices, atol=1e-5)


def test_fortran_ordered_arrays_load(body, tmp_path):
    arrays = {k: np.asfortranarray(v) for k, v in smpl_style_arrays(body, np.float64).items()}
    assert arrays["posedirs"].flags.f_contiguous and not arrays["posedirs"].flags.c_contiguous
    path = tmp_path / "fortran.npz"
    np.savez(path, **arrays)
    model = flsh.load_body_model(path)
    np.testing.assert_array_equal(model.posedirs, body.posedirs)
    np.testing.assert_array_equal(model.weights, body.weights)
    np.testing.assert_array_equal(model.faces, body.faces)


def test_numpy_model_with_missing_or_misshapen_key(body, tmp_path):
    arrays = smpl_style_arrays(body)
    del arrays["weights"]
    np.savez(tmp_path / "missing.npz", **arrays)
    with pytest.raises(ValueError, match="weights"):
        flsh.load_body_model(tmp_path / "missing.npz")
    arrays = smpl_style_arrays(body)
    arrays["v_template"] = arrays["v_template"][:, :2]
    np.savez(tmp_path / "misshapen.npz", **arrays)
    with pytest.raises(ValueError, match=r"v_template.*\(800, 2\)"):
        flsh.load_body_model(tmp_path / "misshapen.npz")


def test_numpy_amass_motion_loads_in_flsh(tmp_path, rng):
    poses = rng.normal(0.0, 0.3, (9, 156)).astype(np.float32)
    trans = rng.normal(0.0, 1.0, (9, 3)).astype(np.float32)
    path = tmp_path / "amass.npz"
    np.savez(path, poses=poses, trans=trans, betas=rng.normal(0.0, 1.0, 16),
             mocap_framerate=np.array(120.0), gender=np.array("female"), dmpls=np.zeros((9, 8)))
    motion = flsh.load_motion(path, up="y")  # the file's values (test_amass.py: the z-up turn)
    assert motion.poses.shape == (9, 72)
    np.testing.assert_array_equal(motion.poses[:, :66], poses[:, :66].astype(np.float64))
    np.testing.assert_array_equal(motion.poses[:, 66:], 0.0)
    np.testing.assert_array_equal(motion.trans, trans.astype(np.float64))
    assert motion.betas.shape == (16,)
    assert motion.fps == 120.0
    assert motion.gender == "female"
