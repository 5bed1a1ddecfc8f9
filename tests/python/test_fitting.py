"""flsh.fitting (fitting β and soft-tissue material to scan files) and
flsh.torch.RolloutSimulator.from_scene (issue 28's fitting jobs, on issue 25's adjoint).

A ROM soft skeleton of a 600-vertex body jumps 12 steps on the ground; its "scans" are the
simulation of a hidden shape and a 2x stiffer tissue."""
import json

import numpy as np
import pytest
import torch

import flsh
import flsh.fitting
import flsh.torch

H = 1.0 / 30.0
STEPS = 12
E1 = "layers.soft_tissue.E1"
TRUE_BETAS = (0.6, -0.4)
ROM = {"simulation": "rom", "resolution": 0.3, "handles": 12, "elastic_cubature": 40,
       "inertial_cubature": 40}


def scene_of(cache, **avatar):
    return {"time_step": H, "duration": STEPS * H, "ground": "auto", "cache_dir": str(cache),
            "avatars": [{"name": "subject", "model": "synthetic", "vertices": 600,
                         "motion": "builtin:jump", **ROM, **avatar}]}


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("fitting")


@pytest.fixture(scope="module")
def scene_path(folder):
    path = folder / "scene.json"
    path.write_text(json.dumps(scene_of(folder / "cache")))
    return path


@pytest.fixture(scope="module")
def simulator(scene_path):
    return flsh.torch.RolloutSimulator.from_scene(scene_path)


def hidden_material(simulator):
    names = simulator.material_names()
    material = torch.tensor(simulator.own_material())
    material[names.index(f"{E1}.log_value")] += np.log(2.0)
    return material


@pytest.fixture(scope="module")
def truth(simulator):
    """(T, V, 3) the hidden subject's simulated surface."""
    with torch.no_grad():
        _, v = flsh.torch.simulate(simulator, betas=torch.tensor(TRUE_BETAS, dtype=torch.float64),
                                   material=hidden_material(simulator), vertices=True)
    return v.numpy()


def test_from_scene_takes_the_scenes_avatar_time_step_and_ground(simulator, scene_path, folder):
    assert simulator.model == "rom" and simulator.num_vertices == 600
    assert simulator.steps == STEPS and simulator.options.time_step == pytest.approx(H)
    assert simulator.mocap is not None
    assert [c.name for c in simulator.colliders] == ["ground"]
    assert simulator.avatar_name == "subject" and simulator.scene_source == str(scene_path)
    # Its rollout is the scene's run (both converged to their tolerances).
    report = flsh.run_scene(str(scene_path), str(folder / "run"), progress=False)
    assert report["unconverged"] == 0
    with np.load(folder / "run" / "states.npz") as states:
        scene_vertices = states["subject_vertices"][1:]
    _, v = flsh.torch.simulate(simulator, vertices=True)
    assert np.abs(scene_vertices).max() > 0.5
    np.testing.assert_allclose(v.numpy(), scene_vertices, atol=2e-5)


def test_from_scene_names_the_avatar(scene_path):
    with pytest.raises(ValueError, match="no avatar named 'nobody'.*avatars: subject"):
        flsh.torch.RolloutSimulator.from_scene(scene_path, avatar="nobody")
    with pytest.raises(ValueError, match=r"index in \[0, 1\)"):
        flsh.torch.RolloutSimulator.from_scene(scene_path, avatar=1)


def write_scans(path, **arrays):
    np.savez(path, **arrays)
    return path


def test_fits_shape_and_stiffness_to_registered_scans(simulator, truth, folder):
    # With a frame at t = 0 (the start state), as flsh.batch's data.npz has: skipped.
    times = H * np.arange(STEPS + 1)
    scans = flsh.fitting.load_scans(
        write_scans(folder / "registered.npz", vertices=np.concatenate([truth[:1], truth]),
                    times=times), simulator)
    assert scans.kind == "vertices" and scans.skipped == 1
    np.testing.assert_array_equal(scans.steps, np.arange(1, STEPS + 1))
    result = flsh.fitting.fit_scans(simulator, scans, betas=2, material=[E1], iterations=40)
    assert result.start_rms > 5e-3
    assert result.final_rms < 1e-5
    np.testing.assert_allclose(result.betas[:2], TRUE_BETAS, atol=1e-4)
    summary = result.summary()
    assert summary["material"][f"{E1}.log_value"]["factor"] == pytest.approx(2.0, rel=1e-3)
    assert summary["shape"]["betas[0]"]["fit"] == pytest.approx(TRUE_BETAS[0], abs=1e-4)
    np.testing.assert_allclose(result.vertices, truth, atol=1e-5)


def surface_points(vertices, faces, rng, count):
    """`count` points per frame drawn over the triangles (unordered)."""
    f = rng.integers(0, len(faces), count)
    w = rng.dirichlet(np.ones(3), count)
    return np.einsum("pk,tpkd->tpd", w, vertices[:, faces[f]])


def test_fits_shape_to_unordered_points_of_some_frames(simulator, truth, folder, rng):
    # Every other frame, points in no particular order.
    frames = np.arange(1, STEPS + 1, 2)
    points = surface_points(truth[frames - 1], np.asarray(simulator.body.faces), rng, 900)
    scans = flsh.fitting.load_scans(
        write_scans(folder / "points.npz", points=points, times=H * frames), simulator)
    assert scans.kind == "points"
    np.testing.assert_array_equal(scans.steps, frames)
    result = flsh.fitting.fit_scans(simulator, scans, betas=2, iterations=30)
    assert result.loss == "points"
    assert result.final_rms < 0.2 * result.start_rms
    np.testing.assert_allclose(result.betas[:2], TRUE_BETAS, atol=0.03)


def write_scene(path, scene):
    path.write_text(json.dumps(scene))
    return path


def test_line_searches_step_back_from_materials_that_are_not_physical(simulator, truth,
                                                                        folder):
    # The shape is wrong and not fitted: the fit lowers E1 until ν12² < E1/E2 fails.
    scans = flsh.fitting.load_scans(write_scans(folder / "short.npz", vertices=truth[:4]),
                                    simulator)
    result = flsh.fitting.fit_scans(simulator, scans, material=[E1], iterations=3)
    assert result.rejected > 0
    assert result.final_loss < result.start_loss
    assert np.isfinite(result.vertices).all()
    assert result.material is not None
    result.save_material(folder / "fitted_material.json")
    scene = write_scene(folder / "fitted.json",
                        scene_of(folder / "cache", materials=str(folder / "fitted_material.json")))
    fitted = flsh.torch.RolloutSimulator.from_scene(scene)
    np.testing.assert_array_equal(fitted.own_material(), result.material)
    assert not np.array_equal(fitted.own_material(), simulator.own_material())


@pytest.mark.parametrize("arrays, message", [
    (dict(surface=np.zeros((2, 600, 3))), "exactly one of the keys 'vertices'"),
    (dict(vertices=np.zeros((2, 600, 3)), points=np.zeros((2, 5, 3))), "exactly one"),
    (dict(vertices=np.zeros((2, 599, 3))), r"key 'vertices': expected \(F, 600, 3\)"),
    (dict(points=np.zeros((2, 5))), r"key 'points': expected a numeric \(F, N, 3\)"),
    (dict(points=np.full((2, 5, 3), np.nan)), "key 'points': frame 0 holds a non-finite"),
    (dict(points=np.full((2, 5, 3), 1e300)), "key 'points': frame 0 holds a non-finite value "
                                             "or one beyond"),
    (dict(points=np.zeros((2, 5, 3)), times=[H, 1.5 * H]), "key 'times': frame 1 at t = 0.05 s "
                                                           "is not a step time"),
    (dict(points=np.zeros((2, 5, 3)), times=[H]), r"key 'times': expected \(2,\)"),
    (dict(points=np.zeros((2, 5, 3)), times=[-H, H]), "before the start"),
    (dict(points=np.zeros((2, 5, 3)), times=[H, H]), "two frames at one step"),
    (dict(points=np.zeros((1, 5, 3)), times=[0.0]), "no frame after t = 0"),
    (dict(points=np.zeros((13, 5, 3))), "frames up to step 13.*has 12 steps"),
])
def test_bad_scan_files_name_the_file_and_key(simulator, tmp_path, arrays, message):
    path = write_scans(tmp_path / "scans.npz", **arrays)
    with pytest.raises(ValueError, match=message) as error:
        flsh.fitting.load_scans(path, simulator)
    assert str(path) in str(error.value)


def test_unreadable_scan_files(simulator, tmp_path):
    with pytest.raises(FileNotFoundError, match="scan file not found"):
        flsh.fitting.load_scans(tmp_path / "missing.npz", simulator)
    (tmp_path / "text.npz").write_text("not a zip archive")
    with pytest.raises(ValueError, match="not a readable .npz"):
        flsh.fitting.load_scans(tmp_path / "text.npz", simulator)
    with pytest.raises(ValueError, match="not a regular file"):
        flsh.fitting.load_scans(tmp_path, simulator)


def test_bad_fit_settings(simulator, truth, tmp_path, body, walk):
    scans = flsh.fitting.load_scans(write_scans(tmp_path / "s.npz", vertices=truth[:2]),
                                    simulator)
    with pytest.raises(ValueError, match="nothing to fit"):
        flsh.fitting.fit_scans(simulator, scans)
    with pytest.raises(ValueError, match="unknown key 'layers.soft_tissue.E4'.*known keys:"):
        flsh.fitting.fit_scans(simulator, scans, material=["layers.soft_tissue.E4"])
    with pytest.raises(ValueError, match="given twice"):
        flsh.fitting.fit_scans(simulator, scans, material=[E1, f"{E1}.log_value"])
    with pytest.raises(ValueError, match=r"integer in \[0, 10\]"):
        flsh.fitting.fit_scans(simulator, scans, betas=11)
    with pytest.raises(ValueError, match="iterations"):
        flsh.fitting.fit_scans(simulator, scans, betas=1, iterations=0)
    with pytest.raises(ValueError, match="noise"):
        flsh.fitting.fit_scans(simulator, scans, betas=1, noise=-1.0)
    skeleton = flsh.torch.RolloutSimulator(body, walk, steps=2)
    with pytest.raises(ValueError, match="no soft-tissue material"):
        flsh.fitting.material_entries(skeleton, [E1])


def test_minimize_finds_the_rosenbrock_minimum():
    def rosenbrock(x):
        return (1 - x[0]) ** 2 + 100 * (x[1] - x[0] ** 2) ** 2

    x, taken = flsh.fitting.minimize(rosenbrock, torch.tensor([-1.2, 1.0], dtype=torch.float64),
                                     200, tolerance_grad=1e-10, tolerance_change=0.0)
    assert 10 < taken < 200
    np.testing.assert_allclose(x.numpy(), [1.0, 1.0], atol=1e-6)


def test_minimize_steps_back_from_where_the_objective_is_not_finite():
    # (x - 2)² where it is defined (x ≤ 1): the minimizer goes to the border, never past it.
    def objective(x):
        if float(x[0]) > 1.0:
            return torch.tensor(float("inf"), dtype=torch.float64)
        return ((x - 2.0) ** 2).sum()

    x, _ = flsh.fitting.minimize(objective, torch.zeros(1, dtype=torch.float64), 50)
    assert 0.99 < float(x[0]) <= 1.0
    with pytest.raises(ValueError, match="not finite at the start"):
        flsh.fitting.minimize(objective, torch.full((1,), 3.0, dtype=torch.float64), 5)
