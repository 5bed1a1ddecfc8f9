"""index.json: the data set of an output folder, one entry per done job of the spec, written
at the end of every run (also an interrupted one). Paths are relative to the output folder, so
the folder can be moved. numpy only; dataset.py builds the PyTorch Dataset on it.

    {"format": "flsh-batch-index", "version": 1, "spec": "/abs/spec.json",
     "frames": 120, "jobs": [{"job": "body000-walk-fem", "data": "jobs/body000-walk-fem/data.npz",
     "frames": 31, "vertices": 600, "simulation": "fem", "motion": "builtin:walk",
     "spec_hash": "…", "flsh_version": "0.1.0"}, …],
     "fits": [{"job": "fit0", "fit": "jobs/fit0/fit.json", "material":
     "jobs/fit0/material.json", "fitted_scene": …, "scans": "/abs/scans.npz", …}, …]}
"""
import json
from pathlib import Path

import numpy as np

from .folders import write_text_atomically

INDEX_NAME = "index.json"
FORMAT = "flsh-batch-index"
VERSION = 1


def write_index(out_dir, spec_path, done):
    """Writes OUT_DIR/index.json listing `done`: (job, manifest record) pairs, in spec order.
    Simulation jobs make the data set ("jobs"); fitting jobs are listed apart ("fits": their
    fit.json and fitted material file)."""
    entries = [{"job": job.id, "data": f"jobs/{job.id}/data.npz",
                "frames": record["frames"], "vertices": record["vertices"],
                "simulation": job.simulation, "motion": job.motion,
                "spec_hash": job.spec_hash, "flsh_version": record["flsh_version"]}
               for job, record in done if job.kind == "simulate"]
    fits = [{"job": job.id, "fit": f"jobs/{job.id}/fit.json",
             "material": record["outputs"].get("material"),
             "fitted_scene": f"jobs/{job.id}/fitted_scene.json", "scans": job.fit["scans"],
             "spec_hash": job.spec_hash, "flsh_version": record["flsh_version"]}
            for job, record in done if job.kind == "fit"]
    index = {"format": FORMAT, "version": VERSION, "spec": str(spec_path),
             "frames": sum(e["frames"] for e in entries), "jobs": entries, "fits": fits}
    write_text_atomically(Path(out_dir) / INDEX_NAME, json.dumps(index, indent=1) + "\n")


def read_index(out_dir):
    """The index of the output folder `out_dir` (a dict as above)."""
    path = Path(out_dir) / INDEX_NAME
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no data set index here (python3 -m flsh.batch "
                                "writes it at the end of a run)")
    with open(path, encoding="utf-8") as f:
        index = json.load(f)
    if index.get("format") != FORMAT or index.get("version") != VERSION:
        raise ValueError(f"{path}: not a version-{VERSION} {FORMAT} file")
    return index


def load_clip(out_dir, entry, fields=None):
    """The arrays of one index entry's data.npz ({name: array}; `fields`: those only)."""
    with np.load(Path(out_dir) / entry["data"]) as data:
        return {name: data[name] for name in (fields or data.files)}
