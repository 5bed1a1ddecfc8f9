"""flsh.batch (issue 28): batches of scenes on a Dask cluster into a data set.

One 2-worker LocalCluster (processes, one thread each) serves the module. Bodies have 400
vertices and runs 3 steps: most of a job's time is generating the synthetic body."""
import functools
import io
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cloudpickle
import dask
import numpy as np
import pytest
from distributed import Client, LocalCluster

import flsh
from flsh import batch

# The kill-once job function below is defined here: ship it to the workers by value.
cloudpickle.register_pickle_by_value(sys.modules[__name__])

H = 1.0 / 60.0
SCENE = {"time_step": H, "duration": 3 * H, "ground": "auto"}
FEM = {"simulation": "fem", "resolution": 0.3}
SPEC = {
    "scene": SCENE,
    "max_unconverged_steps": 0,
    # The two "fem" jobs come first: both start at once on the idle workers, with an empty
    # avatar cache, and build the same volumetric body concurrently.
    "grid": {"avatars": [{"name": "a", "vertices": 400, "betas": [0.5, -0.5]}],
             "motions": ["builtin:walk", "builtin:jump"], "simulations": [FEM]},
    "jobs": [
        {"name": "plain", "avatar": {"vertices": 400}, "motion": "builtin:walk"},
        {"name": "corrupt", "avatar": {"vertices": 400}, "motion": "corrupt.npz"},
        {"name": "stiff", "avatar": {"vertices": 400}, "motion": "builtin:jump",
         "scene": {"newton": {"max_iterations": 1}}},
    ],
}
DONE = ["a-walk-fem", "a-jump-fem", "plain"]
FAILED = ["corrupt", "stiff"]


def write_spec(folder, spec, name="spec.json"):
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(json.dumps(spec))
    return path


def manifest_lines(out):
    return [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]


def arrays(path):
    with np.load(path) as f:
        return {k: f[k] for k in f.files}


@pytest.fixture(scope="module")
def client():
    # A job may kill its worker once and be run again; the second death fails it (Dask's
    # default allows 3 deaths: the test of a job that always kills its worker is faster).
    with dask.config.set({"distributed.scheduler.allowed-failures": 1}), \
            LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                         dashboard_address=None) as cluster, Client(cluster) as c:
        yield c


@pytest.fixture(scope="module")
def first_run(tmp_path_factory, client):
    """SPEC run once on the cluster; the state right after it."""
    folder = tmp_path_factory.mktemp("batch")
    (folder / "corrupt.npz").write_text("not a zip archive")
    spec = write_spec(folder, SPEC)
    plan = batch.load_spec(spec, out=folder / "out")
    log = io.StringIO()
    summary = batch.run_batch(plan, client, stream=log)
    return {"folder": folder, "spec": spec, "plan": plan, "out": plan.out_dir,
            "summary": summary, "log": log.getvalue(),
            "manifest": manifest_lines(plan.out_dir)}


@pytest.fixture(scope="module")
def reference(first_run, tmp_path_factory):
    """The done jobs run one by one with run_job, without Dask, into a fresh output folder
    and avatar cache. In a subprocess with OMP_NUM_THREADS=1, the thread count Dask gives its
    workers: flsh's FEM and ROM results depend on the OpenMP thread count."""
    out = tmp_path_factory.mktemp("reference") / "out"
    script = ("import sys\nfrom flsh.batch import load_spec, run_job\n"
              "plan = load_spec(sys.argv[1], out=sys.argv[2])\n"
              "for job in plan.jobs:\n"
              "    if job.id in sys.argv[3:]:\n"
              "        assert run_job(job, sys.argv[2])['status'] == 'done', job.id\n")
    subprocess.run([sys.executable, "-c", script, str(first_run["spec"]), str(out), *DONE],
                   check=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    return out


def test_results_equal_running_the_jobs_one_by_one_in_process(first_run, reference):
    for job in DONE:
        for name in ("data.npz", "sim/states.npz"):
            ours = arrays(first_run["out"] / "jobs" / job / name)
            theirs = arrays(reference / "jobs" / job / name)
            assert sorted(ours) == sorted(theirs)
            for key in ours:
                assert ours[key].dtype == theirs[key].dtype, (job, name, key)
                np.testing.assert_array_equal(ours[key], theirs[key], err_msg=f"{job} {key}")


def test_a_failing_job_is_reported_and_the_others_finish(first_run):
    summary, out = first_run["summary"], first_run["out"]
    assert (summary.done, summary.failed, summary.skipped, summary.not_run) == (3, 2, 0, 0)
    records = {r["job"]: r for r in first_run["manifest"]}
    assert len(first_run["manifest"]) == 5 and sorted(records) == sorted(DONE + FAILED)
    assert "not an .npz file" in records["corrupt"]["error"]
    assert records["stiff"]["error"] == ("3 of 3 steps did not converge, more than "
                                         "max_unconverged_steps = 0")
    jobs = {job.id: job for job in first_run["plan"].jobs}
    for name, record in records.items():
        assert record["spec_hash"] == jobs[name].spec_hash
        assert record["flsh_version"] == flsh.__version__
        assert record["status"] == ("done" if name in DONE else "failed")
    for name in DONE:
        record = records[name]
        assert record["error"] is None and record["steps"] == 3 and record["frames"] == 4
        assert record["newton_iterations"] >= 3 and record["wall_seconds"] > 0
        assert record["steps_per_second"] > 0
        assert record["outputs"]["data"] == f"jobs/{name}/data.npz"
        assert (out / record["outputs"]["data"]).is_file()
        assert json.loads((out / "jobs" / name / "job.json").read_text())["spec_hash"] == \
            record["spec_hash"]
    assert sorted(p.name for p in (out / "jobs").iterdir()) == sorted(DONE)  # nothing else
    assert "job 'corrupt' failed: ValueError:" in first_run["log"]
    assert "5/5 finished (3 done, 2 failed)" in first_run["log"]
    index = batch.read_index(out)
    assert [e["job"] for e in index["jobs"]] == DONE and index["frames"] == 12


def test_two_jobs_of_one_avatar_at_once_share_one_valid_cache_entry(first_run, reference,
                                                                   capfd):
    records = {r["job"]: r for r in first_run["manifest"]}
    walk, jump = records["a-walk-fem"], records["a-jump-fem"]
    assert walk["pid"] != jump["pid"]  # two workers ...
    assert walk["started_at"] < jump["started_at"] + jump["wall_seconds"]  # ... at once
    assert jump["started_at"] < walk["started_at"] + walk["wall_seconds"]
    cache = sorted(p.name for p in (first_run["out"] / "cache").iterdir())
    assert cache == sorted(p.name for p in (reference / "cache").iterdir())
    assert cache and all(re.fullmatch(r"[0-9a-f]{64}\.npz", name) for name in cache)
    capfd.readouterr()
    flsh.load_scene(first_run["out"] / "jobs" / "a-jump-fem" / "scene.json")
    assert "cache: hit" in capfd.readouterr().err  # format, key and checksum checked


def build_avatar_at_once(cache_dir, barrier, parties):
    """Builds one FEM avatar into `cache_dir` once `parties` processes are ready (a file
    barrier), so that their builds overlap; returns whether its template (tet mesh, the
    large entry, looked up first) and its shaped data (looked up after the template) came
    from the cache."""
    body = flsh.make_synthetic_body(vertices=600)
    Path(barrier, f"ready-{os.getpid()}").touch()
    deadline = time.monotonic() + 300
    while len(list(Path(barrier).glob("ready-*"))) < parties:
        if time.monotonic() > deadline:
            raise TimeoutError("the other builder never came")
        time.sleep(0.001)
    avatar = flsh.SoftAvatar(body, [0.5, -0.5], resolution=1.0, cache_dir=cache_dir)
    avatar.enable_soft_tissue()
    avatar.init_volumetric_data()  # about 0.3 s: the two builds overlap
    report = avatar.build_report
    return report["template_from_cache"], report["data_from_cache"]


def test_workers_building_one_avatar_at_once_store_one_valid_entry(tmp_path, client):
    workers = sorted(client.scheduler_info()["workers"])
    for attempt in range(3):  # a builder descheduled for the whole build: not concurrent
        cache, barrier = tmp_path / f"cache{attempt}", tmp_path / f"barrier{attempt}"
        barrier.mkdir()
        futures = [client.submit(build_avatar_at_once, str(cache), str(barrier), 2,
                                 workers=[w], pure=False) for w in workers[:2]]
        if [template for template, _ in client.gather(futures)] == [False, False]:
            break  # both built the template and stored it under one key
    else:
        pytest.fail("the two builds never overlapped")
    sequential = tmp_path / "sequential"
    build_avatar_at_once(str(sequential), str(tmp_path), 1)
    names = sorted(p.name for p in cache.iterdir())
    assert names == sorted(p.name for p in sequential.iterdir())  # one file per entry
    assert all(re.fullmatch(r"[0-9a-f]{64}\.npz", name) for name in names)  # no temp files
    (tmp_path / "again").mkdir()
    assert build_avatar_at_once(str(cache), str(tmp_path / "again"), 1) == (True, True)


def test_a_second_run_skips_done_jobs_and_redoes_failed_ones(first_run, client):
    out = first_run["out"]
    stale = out / "jobs" / ".plain.tmp-otherhost-123-abcdef01"  # a killed run's leftover
    stale.mkdir()
    (stale / "scene.json").write_text("{}")
    # "plain" finished after its run was interrupted: its folder is there, its line is not.
    manifest = out / "manifest.jsonl"
    manifest.write_text("".join(line + "\n" for line in manifest.read_text().splitlines()
                                if json.loads(line)["job"] != "plain"))
    before = {job: os.stat(out / "jobs" / job / "data.npz") for job in DONE}
    plan = batch.load_spec(first_run["spec"], out=out)
    summary = batch.run_batch(plan, client, stream=io.StringIO())
    assert (summary.done, summary.failed, summary.skipped) == (0, 2, 3)
    lines = manifest_lines(out)
    assert len(lines) == 7 and sorted(r["job"] for r in lines[5:]) == sorted(FAILED)
    assert lines[4]["job"] == "plain" and lines[4]["recovered"] is True
    assert lines[4]["status"] == "done" and "spec" not in lines[4]
    for job in DONE:
        after = os.stat(out / "jobs" / job / "data.npz")
        assert (after.st_ino, after.st_mtime_ns) == (before[job].st_ino, before[job].st_mtime_ns)
    assert not stale.exists()
    assert [e["job"] for e in batch.read_index(out)["jobs"]] == DONE


def test_a_changed_job_runs_again_and_replaces_its_folder(first_run, client):
    spec = json.loads(first_run["spec"].read_text())
    spec["jobs"][0]["scene"] = {"duration": 2 * H}
    path = write_spec(first_run["folder"], spec, "changed.json")
    plan = batch.load_spec(path, out=first_run["out"])
    summary = batch.run_batch(plan, client, stream=io.StringIO())
    assert (summary.done, summary.failed, summary.skipped) == (1, 2, 2)
    record = manifest_lines(first_run["out"])[-3:]
    plain = next(r for r in record if r["job"] == "plain")
    assert plain["status"] == "done" and plain["frames"] == 3
    assert arrays(first_run["out"] / "jobs" / "plain" / "data.npz")["vertices"].shape[0] == 3
    assert sorted(p.name for p in (first_run["out"] / "jobs").iterdir()) == sorted(DONE)


def kill_own_worker_once(job, out_dir, victim, marker):
    """run_job, except that the first attempt of job `victim` kills its worker process
    (SIGKILL) once the job has started writing (its temporary folder holds scene.json)."""
    if job.id == victim and not os.path.exists(marker):
        def watch():
            while True:
                for temp in Path(out_dir, "jobs").glob(f".{victim}.tmp-*"):
                    if (temp / "scene.json").exists():
                        Path(marker).write_text(str(os.getpid()))
                        os.kill(os.getpid(), signal.SIGKILL)
                time.sleep(0.002)
        threading.Thread(target=watch, daemon=True).start()
    return batch.run_job(job, out_dir)


def test_a_killed_worker_loses_no_job_and_leaves_no_partial_output(tmp_path, client):
    spec = write_spec(tmp_path, {
        "scene": SCENE,
        "grid": {"avatars": [{"vertices": 400}],
                 "motions": ["builtin:walk", "builtin:jump", "builtin:stand"]}})
    plan = batch.load_spec(spec, out=tmp_path / "out")
    victim, marker = "avatar0-jump-skeleton", tmp_path / "killed"
    job_function = functools.partial(kill_own_worker_once, victim=victim, marker=str(marker))
    summary = batch.run_batch(plan, client, job_function=job_function, stream=io.StringIO())
    assert marker.exists()  # the victim's first attempt did kill its worker
    assert (summary.done, summary.failed) == (3, 0)
    lines = manifest_lines(plan.out_dir)
    assert sorted(r["job"] for r in lines) == sorted(job.id for job in plan.jobs)
    assert all(r["status"] == "done" for r in lines)
    assert next(r for r in lines if r["job"] == victim)["pid"] != int(marker.read_text())
    jobs = plan.out_dir / "jobs"
    assert sorted(p.name for p in jobs.iterdir()) == sorted(job.id for job in plan.jobs)
    for job in plan.jobs:
        assert sorted(p.name for p in (jobs / job.id).iterdir()) == \
            ["data.npz", "job.json", "log.txt", "scene.json", "sim"]
        assert arrays(jobs / job.id / "data.npz")["vertices"].shape == (4, 400, 3)
    client.wait_for_workers(2)  # the nanny restarted the killed worker


def kill_own_worker(job, out_dir, victim):
    """run_job, except that job `victim` kills its worker process every time it runs."""
    if job.id == victim:
        os.kill(os.getpid(), signal.SIGKILL)
    return batch.run_job(job, out_dir)


def test_a_job_that_always_kills_its_worker_fails_and_the_others_finish(tmp_path, client):
    spec = write_spec(tmp_path, {"scene": SCENE, "grid": {
        "avatars": [{"vertices": 400}], "motions": ["builtin:walk", "builtin:jump"]}})
    plan = batch.load_spec(spec, out=tmp_path / "out")
    victim = "avatar0-walk-skeleton"
    job_function = functools.partial(kill_own_worker, victim=victim)
    summary = batch.run_batch(plan, client, job_function=job_function, stream=io.StringIO())
    assert (summary.done, summary.failed) == (1, 1)
    records = {r["job"]: r for r in manifest_lines(plan.out_dir)}
    assert records[victim]["status"] == "failed"
    assert records[victim]["error"].startswith("KilledWorker: ")
    assert records["avatar0-jump-skeleton"]["status"] == "done"
    assert sorted(p.name for p in (plan.out_dir / "jobs").iterdir()) == ["avatar0-jump-skeleton"]
    client.wait_for_workers(2)


def run_cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "flsh.batch", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True)


@pytest.mark.parametrize("spec, message", [
    ({"grdi": {}}, "grdi: unknown key (known: out, cache_dir, scene, grid, jobs,"),
    ({"grid": {"avatars": [{}], "motions": ["clips/*.npz"]}},
     "grid.motions[0]: matches no file: "),
    ({"grid": {"avatars": [{"vertices": 400}], "motions": ["builtin:walk"],
               "simulations": [{"simulation": "fem", "options": {"tracking_stifness": 1}}]}},
     "grid.simulations[0].options.tracking_stifness: unknown key (known: tracking_stiffness"),
    ({"scene": {"duration": -1}, "jobs": [{}]}, "scene.duration: expected"),
    ("{\"jobs\": [", "malformed JSON at line 1, column 11"),
])
def test_cli_bad_spec_exits_2_with_the_file_and_key(tmp_path, spec, message):
    path = tmp_path / "bad.json"
    path.write_text(spec if isinstance(spec, str) else json.dumps(spec))
    result = run_cli(path, "--out", tmp_path / "out", cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr.startswith(f"python3 -m flsh.batch: error: {path}: ")
    assert message in result.stderr and "Traceback" not in result.stderr
    assert len(result.stderr.splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_cli_runs_a_spec_and_reruns_nothing(tmp_path):
    write_spec(tmp_path, {"scene": SCENE, "jobs": [{"avatar": {"vertices": 400},
                                                    "motion": "builtin:walk"}]})
    result = run_cli("spec.json", "--workers", "1", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "1/1 finished (1 done, 0 failed)" in result.stderr
    assert re.search(r"done +1\n.*failed +0\n", result.stderr)
    assert "jobs/min" in result.stderr
    out = tmp_path / "out" / "batch" / "spec"
    assert (out / "jobs" / "job0" / "data.npz").is_file()
    listing = run_cli("spec.json", "--dry-run", cwd=tmp_path)
    assert listing.returncode == 0 and listing.stdout.startswith("skip  job0  (skeleton, ")
    assert run_cli("spec.json", "--workers", "0", cwd=tmp_path).returncode == 2


def test_dataset_reads_frames_and_clips(first_run):
    out = first_run["out"]
    frames = batch.Dataset(out)
    index = batch.read_index(out)
    assert len(frames) == index["frames"] == sum(e["frames"] for e in index["jobs"])
    first = frames[0]
    assert (first["clip"], first["frame"]) == (0, 0)
    assert tuple(first["vertices"].shape) == (400, 3) and tuple(first["joints"].shape) == (24, 3)
    assert tuple(first["displacements"].shape) == (400, 3)
    assert str(first["vertices"].dtype) == "torch.float32"
    clips = batch.Dataset(out, item="clip", fields=("vertices", "displacements", "faces"))
    assert len(clips) == len(index["jobs"])
    for i, entry in enumerate(index["jobs"]):
        clip = clips[i]
        frames_of_clip = entry["frames"]
        assert tuple(clip["vertices"].shape) == (frames_of_clip, 400, 3)
        assert clip["faces"].shape[1] == 3
        states = arrays(out / "jobs" / entry["job"] / "sim" / "states.npz")
        avatar = "a" if entry["simulation"] == "fem" else "avatar"
        np.testing.assert_array_equal(clip["vertices"].numpy(),
                                      states[f"{avatar}_vertices"].astype(np.float32))
        moved = np.abs(clip["displacements"].numpy()).max()
        assert moved > 1e-4 if entry["simulation"] == "fem" else moved == 0.0
    last = frames[len(frames) - 1]
    assert (last["clip"], last["frame"]) == (len(clips) - 1, index["jobs"][-1]["frames"] - 1)
    with pytest.raises(IndexError):
        frames[len(frames)]


def test_spec_hash_covers_the_job_not_where_it_runs(tmp_path):
    spec = {"scene": SCENE, "grid": {"avatars": {"samples": 2, "seed": 7, "vertices": 400},
                                     "motions": ["builtin:walk"]}}
    first = batch.load_spec(write_spec(tmp_path, spec), out=tmp_path / "a")
    again = batch.load_spec(write_spec(tmp_path, {**spec, "cache_dir": "elsewhere"}),
                            out=tmp_path / "b")
    assert [j.id for j in first.jobs] == ["body000-walk-skeleton", "body001-walk-skeleton"]
    assert [j.spec_hash for j in first.jobs] == [j.spec_hash for j in again.jobs]
    assert first.jobs[0].scene["avatars"][0]["betas"] != first.jobs[1].scene["avatars"][0]["betas"]
    longer = batch.load_spec(write_spec(tmp_path, {**spec, "scene": {**SCENE, "duration": 0.1}}))
    assert all(a.spec_hash != b.spec_hash for a, b in zip(first.jobs, longer.jobs))
