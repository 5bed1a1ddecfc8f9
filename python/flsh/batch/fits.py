"""A spec's "fits": fitting jobs, one per subject (scan file), each fitting the body shape and
soft-tissue material of one avatar of its scene to the subject's scans (flsh.fitting; docs/batch.md
"Fitting jobs").

    "fit":  {"betas": 2, "material": ["layers.soft_tissue.E1"], "iterations": 30},
    "fits": [{"name": "dyna", "scans": "scans/*.npz", "motion": "builtin:jump",
              "simulation": "rom", "avatar": {"model": "synthetic"}, "fit": {...}}]

A glob in "scans" makes one job per file (ids NAME-STEM, or STEM without a name; the folder's
name instead of the stem when stems repeat, as in a data set's jobs/*/data.npz). The top-level
"fit" holds defaults every entry's "fit" overrides key by key."""
import hashlib
from pathlib import Path

from .checks import child
from .grid import Part, id_part
from .spec import read_scene_settings

FIT_ENTRY_KEYS = ("name", "scans", "avatar", "motion", "simulation", "scene", "fit")
FIT_KEYS = ("betas", "material", "iterations", "noise")
FIT_DEFAULTS = {"betas": 0, "material": [], "iterations": 30, "noise": 0.002}
MAX_ITERATIONS = 10000


def read_fit_settings(reader, value, key, base=None):
    """A "fit" object laid over `base` (the defaults): betas (leading shape components fitted,
    0-300), material (material-file key paths or entry names, each once), iterations (1-10000),
    noise (m > 0)."""
    reader.object(value, key, FIT_KEYS)
    settings = dict(base if base is not None else FIT_DEFAULTS)
    if "betas" in value:
        settings["betas"] = reader.integer(value["betas"], child(key, "betas"), 0, 300)
    if "material" in value:
        keys = reader.list(value["material"], child(key, "material"))
        for i, name in enumerate(keys):
            reader.string(name, child(child(key, "material"), i))
            if name in keys[:i]:
                reader.fail(child(child(key, "material"), i), f"'{name}' is given twice")
        settings["material"] = list(keys)
    if "iterations" in value:
        settings["iterations"] = reader.integer(value["iterations"], child(key, "iterations"), 1,
                                                MAX_ITERATIONS)
    if "noise" in value:
        settings["noise"] = reader.number(value["noise"], child(key, "noise"), positive=True)
    return settings


def file_sha256(path):
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def fit_jobs(expander, value, key, defaults):
    """The Jobs of a "fits" list (expander: grid.Expander; defaults: the top-level "fit")."""
    r = expander.r
    jobs = []
    for i, item in enumerate(r.list(value, key, 1)):
        where = child(key, i)
        r.object(item, where, FIT_ENTRY_KEYS)
        settings = read_fit_settings(r, item.get("fit", {}), child(where, "fit"), defaults)
        if settings["betas"] == 0 and not settings["material"]:
            r.fail(child(where, "fit"), 'nothing to fit: give "betas" > 0 or "material" keys '
                                        '(here or in the top-level "fit")')
        if "scans" not in item:
            r.fail(child(where, "scans"), "missing (a scan file .npz, or a glob of them: one "
                                          "job per file)")
        scans = expander.files(r.string(item["scans"], child(where, "scans")),
                               child(where, "scans"), "scan file")
        name = r.name(item["name"], child(where, "name")) if "name" in item else None
        avatar = expander.avatar(item.get("avatar", {}), child(where, "avatar"), "avatar")[0]
        motion = (expander.motion(item["motion"], child(where, "motion"))[0] if "motion" in item
                  else None)
        simulation = expander.simulation(item.get("simulation", "rom"),
                                         child(where, "simulation"))[0]
        if simulation.fields["simulation"] == "skeleton" and settings["material"]:
            r.fail(child(where, "fit"), "material keys on a skeleton avatar: it has no soft "
                                        'tissue (use "simulation": "fem" or "rom")')
        scene = item.get("scene", {})
        read_scene_settings(r, scene, child(where, "scene"))
        variant = Part("", scene, child(where, "scene"))
        motion = motion or Part("", {}, child(where, "motion"))
        for path, stem in zip(scans, file_names(scans)):
            if len(scans) > 1:
                job_id = f"{name}-{stem}"[:64] if name else stem
            else:
                job_id = name or f"fit{i}"
            job = expander.job(job_id, child(where, "name"), avatar, motion, simulation, variant)
            job.fit = {**settings, "scans": path, "scans_sha256": file_sha256(path)}
            jobs.append(job)
    return jobs


def file_names(paths):
    """The names of scan files in job ids: their stems, or, when stems repeat (a glob over
    data sets' jobs/*/data.npz), their folders' names."""
    stems = [id_part(Path(p).stem) for p in paths]
    if len(set(stems)) == len(stems):
        return stems
    return [id_part(Path(p).parent.name) for p in paths]
