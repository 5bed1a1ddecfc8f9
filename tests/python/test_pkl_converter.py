"""tools/smpl_pkl_to_npz.py: converts SMPL .pkl files (chumpy arrays, scipy.sparse J_regressor)
without chumpy, and fails cleanly (non-zero exit, a message naming file and key, no output)
on bad input.

The fake .pkl files are pickled with stand-in classes registered as modules 'chumpy',
'chumpy.ch' and 'chumpy.reordering' only while pickling; the converter then runs in a
subprocess where importing chumpy raises.
"""
import os
import pickle
import subprocess
import sys
import types
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse

CONVERTER = Path(__file__).resolve().parents[2] / "tools" / "smpl_pkl_to_npz.py"
V, J, K, F = 20, 24, 10, 12
SMPL_PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]
SMPL_KEYS = {"v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f"}


@contextmanager
def fake_chumpy():
    """Registers modules chumpy, chumpy.ch (class Ch) and chumpy.reordering (class Select),
    shaped like chumpy's pickles (Ch keeps its value in __dict__['x']), for pickling only."""
    names = ("chumpy", "chumpy.ch", "chumpy.reordering")
    saved = {name: sys.modules.get(name) for name in names}
    modules = {name: types.ModuleType(name) for name in names}

    class Ch:
        def __init__(self, x):
            self.x = x
            self._dirty_vars = {"x"}
            self._itr = None
            self._depends_on_deps = {}

        def __getstate__(self):  # like chumpy: the __dict__ minus unpicklable caches
            return dict(self.__dict__)

    class Select:  # an expression: no stored value 'x'
        def __init__(self, a, idxs):
            self.a = a
            self.idxs = idxs

    for cls, module in ((Ch, "chumpy.ch"), (Select, "chumpy.reordering")):
        cls.__module__ = module
        cls.__qualname__ = cls.__name__
        setattr(modules[module], cls.__name__, cls)
    sys.modules.update(modules)
    try:
        yield types.SimpleNamespace(Ch=Ch, Select=Select)
    finally:
        for name, module in saved.items():
            if module is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = module


def reference_arrays(seed=0):
    """SMPL-shaped arrays in the dtypes of the official file."""
    rng = np.random.default_rng(seed)
    weights = rng.random((V, J))
    weights /= weights.sum(axis=1, keepdims=True)
    regressor = np.zeros((J, V))
    regressor[np.arange(J), np.arange(J) % V] = 1.0
    regressor[3, 7] = 0.25
    kintree = np.stack([SMPL_PARENTS, np.arange(J)]).astype(np.int64)
    kintree[0, 0] = 2**32 - 1  # -1 stored as uint32, as in the official file
    return {
        "v_template": rng.normal(size=(V, 3)),
        "shapedirs": rng.normal(size=(V, 3, K)),
        "posedirs": rng.normal(size=(V, 3, 9 * (J - 1))),
        "J_regressor": regressor,
        "weights": weights,
        "kintree_table": kintree.astype(np.uint32),
        "f": rng.integers(0, V, size=(F, 3)).astype(np.uint32),
    }


def smpl_pickle_dict(ch, arrays):
    """A dict shaped like the official SMPL .pkl: chumpy arrays, a sparse J_regressor, extras."""
    nested = ch.Ch(ch.Ch(arrays["shapedirs"]))  # a Ch whose value is itself a Ch
    return {
        "v_template": ch.Ch(arrays["v_template"]),
        "shapedirs": nested,
        "posedirs": arrays["posedirs"],  # a plain array in some releases
        "J_regressor": scipy.sparse.csc_matrix(arrays["J_regressor"]),
        "weights": ch.Ch(arrays["weights"]),
        "kintree_table": arrays["kintree_table"],
        "f": arrays["f"],
        "J": ch.Select(ch.Ch(arrays["v_template"]), np.arange(J)),  # dropped by the converter
        "bs_style": "lbs",
        "bs_type": "lrotmin",
        "weights_prior": ch.Ch(arrays["weights"]),
        "vert_sym_idxs": np.arange(V),
    }


def write_pickle(path, payload, protocol=2):
    with open(path, "wb") as handle:
        pickle.dump(payload, handle, protocol=protocol)
    return path


@pytest.fixture
def no_chumpy_env(tmp_path):
    """Environment in which `import chumpy` raises, even where chumpy is installed."""
    poison = tmp_path / "poison" / "chumpy"
    poison.mkdir(parents=True)
    (poison / "__init__.py").write_text("raise ImportError('chumpy must not be needed')\n")
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "PYTHONPATH": str(poison.parent),
           "HOME": str(tmp_path)}
    check = subprocess.run([sys.executable, "-c", "import chumpy"], env=env, capture_output=True)
    assert check.returncode != 0
    return env


def run_converter(env, *args):
    return subprocess.run([sys.executable, str(CONVERTER), *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("protocol", [0, 2])
def test_converts_official_style_pickle(tmp_path, no_chumpy_env, protocol):
    arrays = reference_arrays()
    with fake_chumpy() as ch:
        pkl = write_pickle(tmp_path / "basicModel_f.pkl", smpl_pickle_dict(ch, arrays), protocol)
    out = tmp_path / "smpl_female.npz"
    result = run_converter(no_chumpy_env, pkl, out)
    assert result.returncode == 0, result.stderr
    assert f"V={V} vertices, F={F} faces, J={J} joints, K={K} shape components" in result.stdout
    assert len(result.stdout.strip().splitlines()) == 1

    with np.load(out) as npz:
        assert set(npz.files) == SMPL_KEYS
        for key in ("v_template", "shapedirs", "posedirs", "J_regressor", "weights"):
            assert npz[key].dtype == np.float64, key
            np.testing.assert_array_equal(npz[key], arrays[key].astype(np.float64), err_msg=key)
        assert npz["J_regressor"].shape == (J, V)  # dense
        assert npz["kintree_table"].dtype == np.int64
        assert npz["kintree_table"][0, 0] == -1
        np.testing.assert_array_equal(npz["kintree_table"][0], SMPL_PARENTS)
        np.testing.assert_array_equal(npz["kintree_table"][1], np.arange(J))
        assert npz["f"].dtype == np.int64
        np.testing.assert_array_equal(npz["f"], arrays["f"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["basicModel_f.pkl", "poison",
                                                          "smpl_female.npz"]


def test_default_output_path_and_float32_input(tmp_path, no_chumpy_env):
    arrays = reference_arrays(seed=1)
    arrays["v_template"] = arrays["v_template"].astype(np.float32)
    arrays["kintree_table"] = arrays["kintree_table"].astype(np.int64)  # root 4294967295 in int64
    arrays["f"] = arrays["f"].astype(np.float64)  # integral floats are accepted
    with fake_chumpy() as ch:
        pkl = write_pickle(tmp_path / "model.pkl", smpl_pickle_dict(ch, arrays))
    result = run_converter(no_chumpy_env, pkl)
    assert result.returncode == 0, result.stderr
    with np.load(tmp_path / "model.npz") as npz:
        np.testing.assert_array_equal(npz["v_template"], arrays["v_template"].astype(np.float64))
        assert npz["kintree_table"][0, 0] == -1
        assert npz["f"].dtype == np.int64


def test_help(no_chumpy_env):
    result = run_converter(no_chumpy_env, "--help")
    assert result.returncode == 0
    assert "usage" in result.stdout and "chumpy" in result.stdout


def bad_payloads(ch):
    good = reference_arrays()
    cases = {}
    missing = smpl_pickle_dict(ch, good)
    del missing["posedirs"]
    cases["missing key"] = (missing, ["missing key(s) posedirs"])
    wrong = smpl_pickle_dict(ch, good)
    wrong["posedirs"] = np.zeros((V, 3, 200))
    cases["wrong shape"] = (wrong, ["key 'posedirs'", "expected shape (20, 3, 207), got (20, 3, 200)"])
    mismatch = smpl_pickle_dict(ch, good)
    mismatch["weights"] = ch.Ch(np.full((V + 1, J), 1.0 / J))
    cases["V mismatch"] = (mismatch, ["key 'weights'", "expected shape (20, 24), got (21, 24)"])
    nan = smpl_pickle_dict(ch, good)
    nan["v_template"] = ch.Ch(np.full((V, 3), np.nan))
    cases["NaN"] = (nan, ["key 'v_template' contains NaN or Inf"])
    expression = smpl_pickle_dict(ch, good)
    expression["shapedirs"] = ch.Select(ch.Ch(good["shapedirs"]), np.arange(3))
    cases["chumpy expression"] = (expression, ["key 'shapedirs'", "chumpy.reordering.Select",
                                               "without a stored value"])
    text = smpl_pickle_dict(ch, good)
    text["f"] = np.array(["a", "b", "c"])
    cases["string faces"] = (text, ["key 'f'", "expected integers"])
    faces = smpl_pickle_dict(ch, good)
    faces["f"] = np.full((F, 3), V, dtype=np.int64)
    cases["face index"] = (faces, ["key 'f'", "[0, 19]"])
    cases["not a dict"] = ([1, 2, 3], ["expected a pickled dict"])
    return cases


@pytest.mark.parametrize("case", ["missing key", "wrong shape", "V mismatch", "NaN",
                                  "chumpy expression", "string faces", "face index", "not a dict"])
def test_bad_model_fails_cleanly(tmp_path, no_chumpy_env, case):
    with fake_chumpy() as ch:
        payload, expected = bad_payloads(ch)[case]
        pkl = write_pickle(tmp_path / "bad.pkl", payload)
    out = tmp_path / "out.npz"
    out.write_bytes(b"previous contents")  # a failed conversion must not touch it
    result = run_converter(no_chumpy_env, pkl, out)
    assert result.returncode == 1, result.stdout
    assert "smpl_pkl_to_npz: error:" in result.stderr
    assert str(pkl) in result.stderr
    for text in expected:
        assert text in result.stderr, (text, result.stderr)
    assert "Traceback" not in result.stderr
    assert out.read_bytes() == b"previous contents"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.pkl", "out.npz", "poison"]


def test_garbage_truncated_and_missing_files(tmp_path, no_chumpy_env):
    garbage = tmp_path / "garbage.pkl"
    garbage.write_bytes(b"this is not a pickle at all\x00\x01")
    arrays = reference_arrays()
    with fake_chumpy() as ch:
        blob = pickle.dumps(smpl_pickle_dict(ch, arrays), protocol=2)
    truncated = tmp_path / "truncated.pkl"
    truncated.write_bytes(blob[: len(blob) // 2])
    for source in (garbage, truncated, tmp_path / "missing.pkl"):
        out = tmp_path / "out.npz"
        result = run_converter(no_chumpy_env, source, out)
        assert result.returncode == 1, (source, result.stdout)
        assert str(source) in result.stderr
        assert "Traceback" not in result.stderr
        assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["garbage.pkl", "poison",
                                                          "truncated.pkl"]


def test_refuses_pickles_that_run_code(tmp_path, no_chumpy_env):
    marker = tmp_path / "pwned"

    class Exploit:
        def __reduce__(self):
            return (os.system, ("touch " + str(marker),))

    pkl = write_pickle(tmp_path / "evil.pkl", {"v_template": Exploit()})
    result = run_converter(no_chumpy_env, pkl, tmp_path / "out.npz")
    assert result.returncode == 1
    assert "refusing to unpickle" in result.stderr
    assert not marker.exists()
    assert not (tmp_path / "out.npz").exists()


def test_missing_output_directory(tmp_path, no_chumpy_env):
    with fake_chumpy() as ch:
        pkl = write_pickle(tmp_path / "model.pkl", smpl_pickle_dict(ch, reference_arrays()))
    result = run_converter(no_chumpy_env, pkl, tmp_path / "nowhere" / "out.npz")
    assert result.returncode == 1
    assert "does not exist" in result.stderr
    assert not (tmp_path / "nowhere").exists()


def test_converts_smplh_pickle_that_flsh_reads_with_merged_hands(tmp_path, no_chumpy_env):
    """SMPL-H (MANO's SMPLH_*.pkl layout: 52 joints, 16 shape components, hand PCA extras)
    converts like SMPL, and flsh reads the result as SMPL's 24 joints (docs/formats.md)."""
    import flsh

    parents = SMPL_PARENTS[:22]
    for wrist in (20, 21):
        for _ in range(5):
            parents = parents + [wrist, len(parents), len(parents) + 1]
    rng = np.random.default_rng(3)
    Jh, Kh = 52, 16
    weights = rng.random((V, Jh))
    weights /= weights.sum(axis=1, keepdims=True)
    regressor = np.zeros((Jh, V))
    regressor[np.arange(Jh), np.arange(Jh) % V] = 1.0
    kintree = np.stack([parents, np.arange(Jh)]).astype(np.int64)
    kintree[0, 0] = 2**32 - 1
    arrays = {
        "v_template": rng.normal(size=(V, 3)),
        "shapedirs": rng.normal(size=(V, 3, Kh)),
        "posedirs": rng.normal(size=(V, 3, 9 * (Jh - 1))),
        "J_regressor": regressor,
        "weights": weights,
        "kintree_table": kintree.astype(np.uint32),
        "f": rng.integers(0, V, size=(F, 3)).astype(np.uint32),
    }
    with fake_chumpy() as ch:
        payload = smpl_pickle_dict(ch, arrays)
        payload["J"] = ch.Select(ch.Ch(arrays["v_template"]), np.arange(Jh))
        payload["hands_componentsl"] = rng.normal(size=(45, 45))
        payload["hands_meanl"] = rng.normal(size=45)
        pkl = write_pickle(tmp_path / "SMPLH_female.pkl", payload)
    out = tmp_path / "smplh_female.npz"
    result = run_converter(no_chumpy_env, pkl, out)
    assert result.returncode == 0, result.stderr
    assert f"J={Jh} joints, K={Kh} shape components" in result.stdout

    model = flsh.load_body_model(out)
    assert model.family == "SMPL-H"
    assert model.num_joints == 24 and model.num_betas == Kh
    np.testing.assert_array_equal(model.parents, SMPL_PARENTS)
    # Each hand joint carries its 15 fingers' weights.
    np.testing.assert_allclose(model.weights[:, 22], weights[:, 22:37].sum(axis=1), atol=1e-12)
    np.testing.assert_allclose(model.weights[:, 23], weights[:, 37:52].sum(axis=1), atol=1e-12)
    np.testing.assert_array_equal(model.posedirs[..., :189], arrays["posedirs"][..., :189])
    np.testing.assert_array_equal(model.posedirs[..., 189:], 0.0)
