"""One job, run where Dask puts it (or in-process): its scene file, flsh.run_scene, data.npz,
job.json, all written into a hidden temporary folder that is renamed into place at the end.

run_job never raises for a failing job: it returns the job's manifest record with status
"failed" and the error (a KeyboardInterrupt still propagates)."""
import functools
import hashlib
import json
import os
import shutil
import socket
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

import flsh

from . import folders
from .data import frame_arrays

LOG_TAIL_LINES = 20


class JobFailed(RuntimeError):
    """A run that completed but fails the spec's requirements (max_unconverged_steps)."""


def flsh_version():
    """flsh.__version__ (the project version, "0.1.0"; it changes with releases only)."""
    return getattr(flsh, "__version__", "unknown")


@functools.lru_cache(maxsize=None)
def flsh_build():
    """The first 16 hex digits of the sha256 of the compiled module flsh._flsh: tells two
    builds of one version apart (recorded in the manifest, not used to skip jobs)."""
    with open(flsh._flsh.__file__, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()[:16]


@contextmanager
def output_to(path):
    """Sends this process's stdout and stderr (file descriptors 1 and 2: flsh's C++ messages
    too) to the file `path` for the duration."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    try:
        with open(path, "ab") as log:
            os.dup2(log.fileno(), 1)
            os.dup2(log.fileno(), 2)
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved:
            os.close(fd)


def log_tail(path, lines=LOG_TAIL_LINES):
    try:
        return "\n".join(Path(path).read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return ""


def base_record(job):
    """The manifest fields of `job` known before it runs."""
    return {"job": job.id, "spec_hash": job.spec_hash, "flsh_version": flsh_version(),
            "flsh_build": flsh_build(), "simulation": job.simulation, "motion": job.motion,
            "host": socket.gethostname(), "pid": os.getpid(), "started_at": time.time(),
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS")}


def run_statistics(report, avatar):
    """The manifest's figures of one flsh.run_scene report."""
    steps = report["steps"]
    seconds = report["simulation_seconds"]
    return {
        "steps": steps, "frames": report["frames"],
        "steps_per_second": steps / seconds if seconds > 0 else None,
        "newton_iterations": report["newton_iterations"],
        "newton_iterations_per_step": report["newton_iterations"] / steps if steps else None,
        "factorizations": report["factorizations"], "cg_iterations": report["cg_iterations"],
        "unconverged": report["unconverged"], "at_budget": report["at_budget"],
        "max_contacts": report["max_contacts"],
        "max_displacement_mm": report["max_displacement_mm"].get(avatar),
        "setup_seconds": report["setup_seconds"],
        "simulation_seconds": seconds, "output_seconds": report["output_seconds"],
    }


def run_job(job, out_dir):
    """Runs `job` into OUT_DIR/jobs/JOB_ID and returns its manifest record (a dict); a
    fitting job through fit_job.run_fit_job."""
    if job.kind == "fit":
        from .fit_job import run_fit_job  # noqa: PLC0415 (fit_job imports this module)
        return run_fit_job(job, out_dir)
    return run_in_folder(job, out_dir, simulate_into)


def simulate_into(job, temp, record):
    """A simulation job's work in its temporary folder `temp`: flsh.run_scene of scene.json,
    data.npz; fills `record` (statistics, vertices, outputs)."""
    with output_to(temp / "log.txt"):
        report = flsh.run_scene(str(temp / "scene.json"), str(temp / "sim"), progress=False)
        record.update(run_statistics(report, job.avatar))
        limit = job.max_unconverged_steps
        if limit is not None and report["unconverged"] > limit:
            raise JobFailed(f"{report['unconverged']} of {report['steps']} steps did not "
                            f"converge, more than max_unconverged_steps = {limit}")
        arrays = frame_arrays(temp / "sim" / "states.npz", job.avatar, job.simulation,
                              job.data_dtype)
    np.savez(temp / "data.npz", **arrays)
    written = [f"sim/{name}" for name in report["written"]]
    if not job.keep_states:
        (temp / "sim" / "states.npz").unlink()
        written.remove("sim/states.npz")
        if not any((temp / "sim").iterdir()):
            (temp / "sim").rmdir()
    folder = f"jobs/{job.id}"
    record.update(vertices=int(arrays["vertices"].shape[1]),
                  outputs={"folder": folder, "data": f"{folder}/data.npz",
                           "scene": f"{folder}/scene.json", "log": f"{folder}/log.txt",
                           "flsh": [f"{folder}/{name}" for name in written]})


def run_in_folder(job, out_dir, work):
    """What every job does around its work: its manifest record, a hidden temporary folder
    holding scene.json, then `work(job, temp, record)`, job.json, and the folder renamed into
    place as OUT_DIR/jobs/JOB_ID. Returns the record; an exception in the work makes it a
    "failed" record (the temporary folder removed), a KeyboardInterrupt propagates."""
    started = time.perf_counter()
    record = base_record(job)
    record["kind"] = job.kind
    jobs_dir = Path(out_dir) / "jobs"
    jobs_dir.mkdir(parents=True, exist_ok=True)
    temp = folders.make_temp(jobs_dir, job.id)
    try:
        (temp / "scene.json").write_text(json.dumps(job.scene, indent=1) + "\n")
        work(job, temp, record)
        record.update(status="done", error=None, wall_seconds=time.perf_counter() - started)
        (temp / "job.json").write_text(json.dumps({**record, "spec": job.content()}, indent=1)
                                       + "\n")
        folders.place(temp, jobs_dir / job.id)
        return record
    except Exception as error:
        text = str(error) if isinstance(error, JobFailed) else f"{type(error).__name__}: {error}"
        record.update(status="failed", error=text, log_tail=log_tail(temp / "log.txt"),
                      wall_seconds=time.perf_counter() - started)
        shutil.rmtree(temp, ignore_errors=True)
        return record
    except BaseException:
        shutil.rmtree(temp, ignore_errors=True)
        raise
