"""A batch spec file read into a Plan: the output and cache folders and the jobs of its
"grid" and "jobs" (grid.py). Everything is checked before anything is written, flsh's own
scene checks included (scene_check.py)."""
from pathlib import Path

from . import scene_check
from .checks import Reader, read_json
from .errors import BatchError
from .fits import fit_jobs, read_fit_settings
from .grid import Expander
from .spec import Plan, read_scene_settings

TOP_KEYS = ("out", "cache_dir", "scene", "grid", "jobs", "fits", "fit", "max_unconverged_steps",
            "data_dtype")
DATA_DTYPES = ("float32", "float64")


def load_spec(path, out=None, check_scenes=True):
    """Reads and checks the spec file at `path` into a Plan; `out` (the CLI's --out) overrides
    the spec's "out". Raises SpecError (file, key, what was expected), or BatchError for an
    `out` that is a file, and writes nothing.
    check_scenes=False skips flsh's checks of the generated scenes (faster, less safe)."""
    path = Path(path)
    reader = Reader(path)
    spec = reader.object(read_json(path), "", TOP_KEYS)
    spec_dir = path.resolve().parent
    if not any(k in spec for k in ("grid", "jobs", "fits")):
        reader.fail("", 'expected "grid", "jobs" or "fits" (or several): the spec lists no job')

    out_dir = Path(out if out is not None else
                   reader.string(spec.get("out", f"out/batch/{path.stem}"), "out"))
    out_dir = out_dir.resolve()
    if out_dir.exists() and not out_dir.is_dir():
        if out is not None:
            raise BatchError(f"--out: {out_dir} is a file, expected a folder")
        reader.fail("out", f"expected a folder, but {out_dir} is a file")
    cache_dir = (spec_dir / reader.string(spec["cache_dir"], "cache_dir")
                 if "cache_dir" in spec else out_dir / "cache").resolve()
    if cache_dir.exists() and not cache_dir.is_dir():
        reader.fail("cache_dir", f"expected a folder, but {cache_dir} is a file")

    limit = spec.get("max_unconverged_steps")
    settings = {
        "max_unconverged_steps":
            None if limit is None else reader.integer(limit, "max_unconverged_steps", 0),
        "data_dtype": reader.choice(spec.get("data_dtype", "float32"), "data_dtype",
                                    DATA_DTYPES),
    }
    common = read_scene_settings(reader, spec.get("scene", {}), "scene")
    expander = Expander(reader, spec_dir, common, str(cache_dir), settings)
    jobs = []
    if "grid" in spec:
        jobs += expander.grid(spec["grid"], "grid")
    if "jobs" in spec:
        jobs += expander.listed(spec["jobs"], "jobs")
    if "fits" in spec:
        defaults = read_fit_settings(reader, spec.get("fit", {}), "fit")
        jobs += fit_jobs(expander, spec["fits"], "fits", defaults)
    elif "fit" in spec:
        reader.fail("fit", 'settings for fitting jobs, but the spec has no "fits"')
    check_unique_ids(reader, jobs)
    if check_scenes:
        scene_check.check_scenes(reader, jobs)
    return Plan(path.resolve(), out_dir, cache_dir, jobs)


def check_unique_ids(reader, jobs):
    """Job ids name folders: two jobs with one id would overwrite each other."""
    seen = {}
    for job in jobs:
        if job.id in seen:
            reader.fail(job.origin["id"], f"job id '{job.id}' is already the id of the job made "
                                          f"by {seen[job.id]}; give one of them another name")
        seen[job.id] = job.origin["id"]
