"""Scenes from files in the library (issue 24, item 6): flsh.load_scene returns a ready Scene,
flsh.run_scene does what `flsh simulate` does, with the same outputs."""
import json
import os
import subprocess

import numpy as np
import pytest

import flsh

SCENE = {
    "time_step": 1.0 / 60.0,
    "duration": 0.2,
    "ground": "auto",
    "avatars": [{"name": "walker", "vertices": 600, "motion": "builtin:walk"}],
    "colliders": [{"name": "ball", "type": "sphere", "center": [0.0, 0.0, 0.6], "radius": 0.1,
                   "velocity": [0.0, 0.0, -2.0]}],
    "outputs": {"dir": "out", "ply": False, "gltf": False, "png": False},
}


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(SCENE))
    return path


def test_load_scene_returns_an_initialized_scene(scene_file, capfd):
    scene = flsh.load_scene(scene_file)
    assert isinstance(scene, flsh.Scene)
    assert len(scene.simulables) == 1
    err = capfd.readouterr().err
    assert "load_scene: ground: auto, plane at y = " in err
    walker = scene.simulables[0]
    start = walker.get_vertices().copy()
    for _ in range(3):
        scene.step()
    assert np.abs(walker.get_vertices() - start).max() > 1e-3  # it walks
    quiet = flsh.load_scene(scene_file, duration=0.05, verbose=False)
    assert len(quiet.simulables) == 1
    assert capfd.readouterr().err == ""


def test_run_scene_writes_what_flsh_simulate_writes(scene_file, tmp_path, capfd):
    report = flsh.run_scene(scene_file, str(tmp_path / "py_out"), progress=False)
    assert report["written"] == ["states.npz"]
    assert report["steps"] == 12 and report["frames"] == 13
    assert report["avatars"] == ["walker"]
    assert report["colliders"] == 2 and report["ground_height"] < -0.5
    assert report["max_contacts"] > 0
    assert report["unconverged"] == 0
    assert report["iteration_budget"] == 0 and report["at_budget"] == 0  # no preset
    assert "1 avatar(s), 2 collider(s) (ground at y = " in report["summary"]
    assert os.path.isfile(tmp_path / "py_out" / "states.npz")

    flsh_bin = os.environ.get("FLSH_BIN")
    if flsh_bin is None:
        pytest.fail("FLSH_BIN (the flsh program) is not set; ctest sets it")
    subprocess.run([flsh_bin, "simulate", str(scene_file), "--out", str(tmp_path / "cli_out")],
                   check=True, capture_output=True)
    with np.load(tmp_path / "py_out" / "states.npz") as a, \
            np.load(tmp_path / "cli_out" / "states.npz") as b:
        assert sorted(a.files) == sorted(b.files)
        for key in a.files:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_the_realtime_preset_reports_steps_at_its_budget_not_as_unconverged(tmp_path):
    """A small ROM walker under "preset": "realtime": 3 Newton iterations per step, the steps
    that use them all counted apart from unconverged ones (docs/rom.md)."""
    path = tmp_path / "realtime.json"
    path.write_text(json.dumps({
        "preset": "realtime", "time_step": 1 / 30, "duration": 0.2, "ground": "auto",
        "avatars": [{"vertices": 600, "simulation": "rom", "resolution": 0.3,
                     "motion": "builtin:walk", "motion_seconds": 0.5}],
        "outputs": {"png": False, "gltf": False, "ply": False}, "cache_dir": "cache"}))
    report = flsh.run_scene(path, str(tmp_path / "out"), progress=False)
    assert report["steps"] == 6 and report["iteration_budget"] == 3
    assert report["newton_iterations"] <= 3 * 6
    assert report["unconverged"] == 0 and 0 <= report["at_budget"] <= 6
    assert "at the budget of 3 iterations" in report["summary"]


def test_run_scene_errors_name_the_file_and_key(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"avatars": [{"vertices": 600}], "ground": "floor"}))
    with pytest.raises(ValueError, match=r"bad.json: ground: expected \"auto\""):
        flsh.run_scene(bad, str(tmp_path / "out"))
    assert not (tmp_path / "out").exists()
    with pytest.raises(FileNotFoundError):
        flsh.load_scene(tmp_path / "missing.json")
