"""flsh.batch's fitting jobs (spec "fits", issue 28 on issue 25's adjoint): a simulation job
makes the scans of a hidden subject (a 600-vertex FEM body of known shape, its tissue 2x stiffer
along the bone, jumping 12 steps on the ground), and fitting jobs recover the stiffness (and,
from β = 0, the shape) from the data set's data.npz, on a 2-worker LocalCluster.

The FEM, not the ROM: a ROM avatar's basis and cubatures are trained per avatar, its material
included, so a subject simulated from another material file is another discretization (here
0.34 mm RMS from the fit's avatar with the same coefficients), which no coefficient fits."""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from distributed import Client, LocalCluster

import flsh
from flsh import batch

H = 1.0 / 30.0
STEPS = 12
E1 = "layers.soft_tissue.E1"
BETAS = [0.6, -0.4]
FEM = {"simulation": "fem", "resolution": 0.3}


@pytest.fixture(scope="module")
def client():
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as c:
        yield c


def write(path, value):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(value))
    return path


def run(spec_path, client, **kwargs):
    return batch.run_batch(batch.load_spec(spec_path, **kwargs), client)


@pytest.fixture(scope="module")
def subject(tmp_path_factory, client):
    """The hidden subject's data set (one simulation job) and the scene settings it used."""
    folder = tmp_path_factory.mktemp("fits")
    cache = folder / "cache"
    # The ground where "auto" puts it under the body of shape BETAS, fixed for every job.
    probe = write(folder / "probe.json", {
        "time_step": H, "duration": STEPS * H, "ground": "auto", "cache_dir": str(cache),
        "avatars": [{"model": "synthetic", "vertices": 600, "betas": BETAS,
                     "motion": "builtin:jump", **FEM}]})
    parts = flsh.load_scene_avatars(str(probe))
    scene = {"time_step": H, "duration": STEPS * H, "ground": float(parts["colliders"][0].p0[1])}
    # The hidden material: the avatar's own with E1 doubled, as a material file.
    avatar = parts["avatars"][0]["avatar"]
    names = list(avatar.material_parameter_names)
    hidden = avatar.material_parameters.copy()
    hidden[names.index(f"{E1}.log_value")] += np.log(2.0)
    avatar.with_material(hidden).save_material_file(str(folder / "hidden_material.json"))
    spec = write(folder / "simulate.json", {
        "out": str(folder / "data"), "cache_dir": str(cache), "scene": scene,
        "data_dtype": "float64", "max_unconverged_steps": 0,
        "jobs": [{"name": "hidden", "motion": "builtin:jump",
                  "avatar": {"vertices": 600, "betas": BETAS},
                  "simulation": {**FEM, "materials": str(folder / "hidden_material.json")}}]})
    summary = run(spec, client)
    assert summary.done == 1
    return {"folder": folder, "cache": cache, "scene": scene,
            "data": folder / "data" / "jobs" / "hidden" / "data.npz"}


def fit_spec(subject, fits, fit=None):
    folder = subject["folder"]
    return write(folder / "fit.json", {
        "out": str(folder / "fitted"), "cache_dir": str(subject["cache"]),
        "scene": subject["scene"], "fit": fit or {"material": [E1], "iterations": 30},
        "fits": fits})


@pytest.fixture(scope="module")
def fitted(subject, client):
    """Fitting jobs over a glob of two scan files, one of them bad, and a shape fit."""
    folder = subject["folder"]
    scans = folder / "scans"
    scans.mkdir()
    shutil.copy(subject["data"], scans / "good.npz")
    with np.load(subject["data"]) as data:
        np.savez(scans / "bad.npz", vertices=data["vertices"][:, :599], times=data["times"])
    spec = fit_spec(subject, [
        {"name": "subject", "scans": str(scans / "*.npz"), "motion": "builtin:jump",
         "avatar": {"vertices": 600, "betas": BETAS}, "simulation": FEM},
        {"name": "shape", "scans": str(scans / "good.npz"), "motion": "builtin:jump",
         "avatar": {"vertices": 600}, "simulation": FEM,
         "fit": {"betas": 2, "material": [], "iterations": 40}}])
    summary = run(spec, client)
    return {"spec": spec, "summary": summary, "out": folder / "fitted"}


def test_a_fitting_job_recovers_the_stiffness_from_a_data_set(fitted, subject):
    assert fitted["summary"].done == 2 and fitted["summary"].failed == 1
    job = fitted["out"] / "jobs" / "subject-good"
    figures = json.loads((job / "fit.json").read_text())
    entry = figures["material"][f"{E1}.log_value"]
    assert entry["factor"] == pytest.approx(2.0, rel=0.02)
    assert figures["final_rms_mm"] < 0.05 * figures["start_rms_mm"]
    assert figures["scan_kind"] == "vertices" and figures["scan_frames"] == STEPS
    assert figures["skipped_start_frames"] == 1
    # The fitted material file holds the fitted coefficient.
    material = json.loads((job / "material.json").read_text())
    assert material["layers"]["soft_tissue"]["E1"]["value"] == pytest.approx(
        np.exp(entry["fit"]), rel=1e-12)
    with np.load(job / "fitted.npz") as out, np.load(subject["data"]) as data:
        assert out["vertices"].shape == (STEPS, 600, 3)
        np.testing.assert_allclose(out["times"], data["times"][1:], atol=1e-12)
        np.testing.assert_allclose(out["vertices"], data["vertices"][1:], atol=2e-4)


def test_the_fitted_scene_simulates_the_fitted_subject(fitted, subject, tmp_path):
    job = fitted["out"] / "jobs" / "subject-good"
    report = flsh.run_scene(str(job / "fitted_scene.json"), str(tmp_path / "run"),
                            progress=False)
    assert report["unconverged"] == 0
    with np.load(tmp_path / "run" / "states.npz") as states, np.load(subject["data"]) as data:
        vertices = states[[k for k in states.files if k.endswith("_vertices")][0]]
        np.testing.assert_allclose(vertices, data["vertices"], atol=2e-4)


def test_a_shape_fit_from_the_mean_shape(fitted):
    figures = json.loads((fitted["out"] / "jobs" / "shape" / "fit.json").read_text())
    # The subject's avatar was built at β = (0.6, −0.4), the fit's at 0 (then with_shape): their
    # tet meshes differ (each is voxelized from its own rest shape), so β is found to a few
    # hundredths, not exactly.
    np.testing.assert_allclose(figures["betas"][:2], BETAS, atol=0.05)
    assert figures["final_rms_mm"] < 0.3 * figures["start_rms_mm"]
    assert not figures["material"]
    # A soft model's fit always writes its material file (here the avatar's own).
    assert (fitted["out"] / "jobs" / "shape" / "material.json").is_file()


def test_a_bad_scan_file_fails_its_job_only_with_the_file_and_key(fitted):
    records = [json.loads(line) for line in
               (fitted["out"] / "manifest.jsonl").read_text().splitlines()]
    bad = [r for r in records if r["job"] == "subject-bad"]
    assert len(bad) == 1 and bad[0]["status"] == "failed"
    assert "bad.npz: key 'vertices': expected (F, 600, 3)" in bad[0]["error"]
    assert not (fitted["out"] / "jobs" / "subject-bad").exists()
    index = batch.read_index(fitted["out"])
    assert [e["job"] for e in index["fits"]] == ["subject-good", "shape"]
    assert index["jobs"] == []
    good = [r for r in records if r["job"] == "subject-good"][0]
    assert good["kind"] == "fit" and good["outputs"]["material"].endswith("material.json")


def test_a_second_run_skips_done_fits_and_an_edited_scan_file_is_fitted_again(fitted, client,
                                                                                subject):
    summary = run(fitted["spec"], client)
    assert (summary.done, summary.failed, summary.skipped) == (0, 1, 2)
    plan = batch.load_spec(fitted["spec"])
    before = {job.id: job.spec_hash for job in plan.jobs}
    scans = subject["folder"] / "scans" / "good.npz"
    with np.load(scans) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["vertices"] = arrays["vertices"] + 1e-3
    np.savez(scans, **arrays)
    try:
        after = {job.id: job.spec_hash for job in batch.load_spec(fitted["spec"]).jobs}
    finally:
        shutil.copy(subject["data"], scans)
    assert after["subject-good"] != before["subject-good"] and after["shape"] != before["shape"]
    assert after["subject-bad"] == before["subject-bad"]


@pytest.mark.parametrize("entry, fit, message", [
    ({"scans": "missing.npz"}, None, r"fits\[0\]\.scans: scan file not found"),
    ({"scans": "none/*.npz"}, None, r"fits\[0\]\.scans: matches no file"),
    ({}, None, r"fits\[0\]\.scans: missing"),
    ({"scans": "x.npz"}, {"betas": 0, "material": []}, r"fits\[0\]\.fit: nothing to fit"),
    ({"scans": "x.npz", "simulation": "skeleton"}, {"material": [E1]},
     r"fits\[0\]\.fit: material keys on a skeleton avatar"),
    ({"scans": "x.npz", "fit": {"iterations": 0}}, None,
     r"fits\[0\]\.fit\.iterations: expected 1 <= value <= 10000"),
    ({"scans": "x.npz", "fit": {"material": [E1, E1]}}, None,
     r"fits\[0\]\.fit\.material\[1\]: '.*' is given twice"),
    ({"scans": "x.npz", "fit": {"tolerance": 1}}, None, r"fits\[0\]\.fit\.tolerance: unknown key"),
    ({"scans": "x.npz", "scene": {"outputs": {"dir": "x"}}}, None,
     r"fits\[0\]\.scene\.outputs\.dir: set by flsh\.batch"),
])
def test_bad_fit_entries_name_the_spec_key(tmp_path, entry, fit, message):
    (tmp_path / "x.npz").write_bytes(b"")
    spec = write(tmp_path / "spec.json", {
        "scene": {"time_step": H, "duration": STEPS * H},
        "fit": fit or {"material": [E1]}, "fits": [{"avatar": {"vertices": 600}, **entry}]})
    with pytest.raises(batch.SpecError, match=message):
        batch.load_spec(spec, check_scenes=False)


def test_fit_settings_without_fits_are_an_error(tmp_path):
    spec = write(tmp_path / "spec.json", {"jobs": [{"name": "a"}], "fit": {"betas": 1}})
    with pytest.raises(batch.SpecError, match='fit: settings for fitting jobs, but the spec has '
                                              'no "fits"'):
        batch.load_spec(spec, check_scenes=False)



def test_a_glob_over_a_data_sets_jobs_names_the_fits_by_their_folders(tmp_path):
    for job in ("ana", "ben"):
        (tmp_path / "data" / "jobs" / job).mkdir(parents=True)
        (tmp_path / "data" / "jobs" / job / "data.npz").write_bytes(b"")
    spec = write(tmp_path / "spec.json", {
        "fit": {"material": [E1]},
        "fits": [{"scans": "data/jobs/*/data.npz"}, {"name": "x", "scans": "data/jobs/*/*.npz"}]})
    jobs = batch.load_spec(spec, check_scenes=False).jobs
    assert [job.id for job in jobs] == ["ana", "ben", "x-ana", "x-ben"]
    assert all(job.kind == "fit" for job in jobs)
    assert jobs[0].fit["scans"] == str(tmp_path / "data" / "jobs" / "ana" / "data.npz")


def test_the_worked_example_recovers_each_subjects_stiffness(tmp_path, client):
    # docs/batch.md's two specs, copied with their material file: the fit spec reads the
    # subjects' data sets at ../../out/batch/subjects relative to itself.
    examples = Path(__file__).resolve().parents[2] / "examples" / "batch"
    copy = tmp_path / "examples" / "batch"
    shutil.copytree(examples / "materials", copy / "materials")
    for name in ("subjects.json", "fit_subjects.json"):
        shutil.copy(examples / name, copy / name)
    out = tmp_path / "out" / "batch"
    assert run(copy / "subjects.json", client, out=out / "subjects").done == 2
    assert run(copy / "fit_subjects.json", client, out=out / "fit_subjects").done == 2
    for subject in ("ana", "ben"):
        figures = json.loads((out / "fit_subjects" / "jobs" / subject / "fit.json").read_text())
        assert figures["material"][f"{E1}.log_value"]["factor"] == pytest.approx(2.0, rel=1e-3)
