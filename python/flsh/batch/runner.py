"""A Plan run on a Dask cluster: skip the jobs done before, submit the others, append one
manifest line per finished job (in this, the client process), write the data set index.

A worker that dies while running a job (killed, out of memory, a crash in C++) is replaced by
its nanny and the scheduler runs the job again elsewhere, up to the scheduler's
`distributed.scheduler.allowed-failures` times (Dask's default 3; then the job is failed with
a KilledWorker error). Python errors inside a job are not retried: run_job reports them."""
import sys
import uuid
from pathlib import Path

from . import folders
from .errors import BatchError
from .index import write_index
from .job import flsh_version, run_job
from .manifest import Manifest, folder_record, is_done, latest_records
from .progress import Progress


def plan_status(plan, redo=False):
    """(jobs to run, [(job, record)] of the jobs done before, [record] of those of them the
    manifest does not show done: they finished after their run was interrupted)."""
    version = flsh_version()
    latest = latest_records(plan.out_dir)
    todo, skipped, unrecorded = [], [], []
    for job in plan.jobs:
        record = None if redo else folder_record(plan.out_dir, job.id)
        if not is_done(job, record, version):
            todo.append(job)
            continue
        record = {k: v for k, v in record.items() if k != "spec"}
        skipped.append((job, record))
        if not is_done(job, latest.get(job.id), version):
            unrecorded.append({**record, "recovered": True})
    return todo, skipped, unrecorded


def failed_record(job, error):
    """The manifest record of a job whose task itself failed (its workers died too often
    (KilledWorker), it was cancelled, the worker could not import flsh ...): `error` text."""
    return {"job": job.id, "spec_hash": job.spec_hash, "flsh_version": flsh_version(),
            "simulation": job.simulation, "motion": job.motion, "status": "failed",
            "error": error, "wall_seconds": None}


def run_batch(plan, client, *, redo=False, job_function=run_job, stream=None):
    """Runs the jobs of `plan` that are not done yet on the Dask `client`'s cluster and
    returns a progress.Summary. redo=True runs every job again. `job_function(job, out_dir)`
    runs one job on a worker and returns its manifest record (run_job; tests wrap it).

    On KeyboardInterrupt the pending jobs are cancelled and the exception propagates; the
    manifest holds every job that finished, index.json lists the done ones."""
    from distributed import as_completed

    out = Path(plan.out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise BatchError(f"{out}: cannot create the output folder ({error})") from None
    stream = stream or sys.stderr
    with folders.locked(out):
        folders.remove_stale(out / "jobs")
        todo, skipped, unrecorded = plan_status(plan, redo)
        workers = len(client.scheduler_info().get("workers", {}))
        progress = Progress(len(todo), len(skipped), workers, stream)
        progress.header(out)
        finished = {}
        all_finished = False
        try:
            with Manifest(out) as manifest:
                for record in unrecorded:
                    manifest.append(record)
                run = uuid.uuid4().hex[:8]  # keys unique per run: Dask keeps no stale results
                futures = {client.submit(job_function, job, str(out), pure=False,
                                         key=f"flsh-batch-{job.id}-{run}"): job
                           for job in todo}
                try:
                    for future in as_completed(futures):
                        job = futures.pop(future)
                        if future.status == "finished":
                            record = future.result()
                        elif future.status == "cancelled":
                            record = failed_record(job, "cancelled by the scheduler")
                        else:
                            error = future.exception()
                            record = failed_record(job, f"{type(error).__name__}: {error}")
                        future.release()
                        manifest.append(record)
                        finished[job.id] = record
                        progress.finished(record)
                    all_finished = True
                finally:
                    if futures:
                        _cancel(client, list(futures))
        finally:
            done = dict((job.id, record) for job, record in skipped)
            done.update((k, r) for k, r in finished.items() if r["status"] == "done")
            write_index(out, plan.spec_path,
                        [(job, done[job.id]) for job in plan.jobs if job.id in done])
        if all_finished:
            folders.remove_stale(out / "jobs")  # attempts of jobs whose worker died
        return progress.summary()


def _cancel(client, futures):
    """Best effort: pending jobs are dropped; running ones finish their job on the worker,
    and their result is dropped (their folder is complete if it appears)."""
    try:
        client.cancel(futures)
    except Exception:  # noqa: BLE001 (the client may already be closing)
        pass
