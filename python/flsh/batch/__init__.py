"""flsh.batch: many flsh simulations (a grid of avatars, motions, simulation models and scene
settings) run on a Dask cluster into a data set (docs/batch.md).

    python3 -m flsh.batch examples/batch/soft_tissue.json --workers 2

    from flsh import batch
    plan = batch.load_spec("spec.json")            # checked jobs; SpecError on a mistake
    with batch.open_client(workers=2) as client:
        summary = batch.run_batch(plan, client)    # OUT/jobs/ID/, manifest.jsonl, index.json
    frames = batch.Dataset(plan.out_dir)           # a torch Dataset (imports torch)

Dask (python3-distributed) is imported only when a batch runs, torch only by Dataset.
"""
from .cluster import open_client
from .errors import BatchError, SpecError
from .index import load_clip, read_index
from .job import run_job
from .load import load_spec
from .runner import run_batch
from .spec import Job, Plan


def __getattr__(name):
    if name == "Dataset":  # imports torch
        from .dataset import Dataset
        return Dataset
    raise AttributeError(f"module 'flsh.batch' has no attribute '{name}'")


__all__ = ["BatchError", "Dataset", "Job", "Plan", "SpecError", "load_clip", "load_spec",
           "open_client", "read_index", "run_batch", "run_job"]
