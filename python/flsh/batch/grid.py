"""Expansion of a spec's "grid" (avatars x motions x simulations x scenes) and "jobs" into Jobs,
each one complete scene with one avatar. Keys flsh checks itself (betas, options, colliders,
...) are passed through; scene_check.py runs flsh's checks on the result."""
import glob
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import flsh

from .checks import child
from .spec import DEFAULT_OUTPUTS, SCENE_KEYS, Job, read_scene_settings

GRID_KEYS = ("avatars", "motions", "simulations", "scenes")
AVATAR_KEYS = ("name", "model", "vertices", "betas")
SAMPLE_KEYS = ("samples", "seed", "num_betas", "std", "name", "model", "vertices")
MOTION_KEYS = ("motion", "name", "up", "motion_seconds", "offset", "yaw_degrees")
SIMULATIONS = ("skeleton", "fem", "rom")
SIMULATION_KEYS = ("simulation", "name", "resolution", "materials", "basis", "vibration_modes",
                   "modal_columns", "handles", "elastic_cubature", "inertial_cubature",
                   "surface_partition_of_unity", "options")
JOB_KEYS = ("name", "avatar", "motion", "simulation", "scene")
MERGED_SCENE_KEYS = ("outputs", "newton")  # merged key by key; other keys are replaced


def id_part(text):
    """`text` as part of a job id: letters, digits, _ and - (others become _), at most 64."""
    return re.sub(r"[^A-Za-z0-9_-]", "_", text)[:64]


@dataclass
class Part:
    """One value of one grid axis: its name in job ids, the scene keys it sets (avatar keys,
    or top-level keys for a scene variant) and the spec key path it came from."""
    name: str
    fields: dict
    origin: str
    plain: bool = False  # a plain string entry ("builtin:walk", "fem"): its keys map to it


class Expander:
    """Turns grid axes and job entries of one spec into Jobs."""

    def __init__(self, reader, spec_dir, common_scene, cache_dir, settings):
        self.r = reader
        self.spec_dir = Path(spec_dir)
        self.common = common_scene
        self.cache_dir = cache_dir
        self.settings = settings  # max_unconverged_steps, data_dtype

    # --- "grid" ---------------------------------------------------------------------------
    def grid(self, value, key):
        """Every combination of the grid's axes, avatars outermost; ids
        AVATAR-MOTION-SIMULATION (-SCENE when "scenes" is given)."""
        self.r.object(value, key, GRID_KEYS)
        for axis in ("avatars", "motions"):
            if axis not in value:
                self.r.fail(child(key, axis), "missing (a grid needs avatars and motions)")
        avatars = self.avatars(value["avatars"], child(key, "avatars"))
        motions = self.motions(value["motions"], child(key, "motions"))
        simulations = self.parts(value.get("simulations", ["skeleton"]),
                                 child(key, "simulations"), self.simulation, "")
        variants = ([Part("", {}, "scene")] if "scenes" not in value else
                    self.parts(value["scenes"], child(key, "scenes"), self.variant, "scene"))
        jobs = []
        for avatar in avatars:
            for motion in motions:
                for simulation in simulations:
                    for variant in variants:
                        names = [avatar.name, motion.name, simulation.name, variant.name]
                        job_id = "-".join(n for n in names if n)
                        jobs.append(self.job(job_id, key, avatar, motion, simulation, variant))
        return jobs

    def parts(self, value, key, read, prefix):
        """A list axis read item by item (unnamed items: PREFIX<i>); names must be unique
        (they become job ids)."""
        parts = []
        for i, item in enumerate(self.r.list(value, key, 1)):
            parts += read(item, child(key, i), f"{prefix}{i}")
        self.unique_names(parts)
        return parts

    def unique_names(self, parts):
        seen = {}
        for part in parts:
            if part.name in seen:
                self.r.fail(part.origin, f"name '{part.name}' is already the name of "
                                         f"{seen[part.name]}; give one of them a \"name\"")
            seen[part.name] = part.origin

    def avatars(self, value, key):
        if isinstance(value, dict):
            parts = self.sampled_avatars(value, key)
        else:
            parts = self.parts(value, key, self.avatar, "avatar")
        self.unique_names(parts)
        return parts

    def avatar(self, value, key, default_name):
        """An avatar entry: name, model (a body model file or "synthetic"), vertices, betas."""
        self.r.object(value, key, AVATAR_KEYS)
        fields = dict(value)
        fields["name"] = self.r.name(value.get("name", default_name), child(key, "name"))
        if "model" in value:
            fields["model"] = self.model_path(value["model"], child(key, "model"))
        return [Part(fields["name"], fields, key)]

    def sampled_avatars(self, value, key):
        """{"samples": N, "seed", "num_betas", "std", "name", "model", "vertices"}: N avatars
        with betas ~ N(0, std^2) drawn by numpy's default_rng(seed), rounded to 1e-6."""
        r = self.r
        r.object(value, key, SAMPLE_KEYS)
        if "samples" not in value:
            r.fail(child(key, "samples"), "missing (the number of avatars to draw)")
        count = r.integer(value["samples"], child(key, "samples"), 1, 100000)
        seed = r.integer(value.get("seed", 0), child(key, "seed"), 0)
        num_betas = r.integer(value.get("num_betas", 10), child(key, "num_betas"), 1, 300)
        std = r.number(value.get("std", 1.0), child(key, "std"), positive=True)
        prefix = r.name(value.get("name", "body"), child(key, "name"))
        width = max(3, len(str(count - 1)))
        if len(prefix) + width > 64:
            r.fail(child(key, "name"), f"expected at most {64 - width} characters (names are "
                                       f"{prefix}{'0' * width}, ...: at most 64)")
        common = {k: value[k] for k in ("vertices",) if k in value}
        if "model" in value:
            common["model"] = self.model_path(value["model"], child(key, "model"))
        betas = np.round(np.random.default_rng(seed).normal(0.0, std, (count, num_betas)), 6)
        return [Part(f"{prefix}{i:0{width}d}",
                     {"name": f"{prefix}{i:0{width}d}", **common, "betas": row.tolist()}, key)
                for i, row in enumerate(betas)]

    def motions(self, value, key):
        parts = []
        for i, item in enumerate(self.r.list(value, key, 1)):
            parts += self.motion(item, child(key, i), allow_glob=True)
        self.unique_names(parts)
        return parts

    def motion(self, value, key, allow_glob=False):
        """A motion entry: "builtin:NAME", a motion .npz (a glob in a grid: one motion per
        file, sorted) or {"motion": ..., "name", "up", "motion_seconds", "offset",
        "yaw_degrees"}. The name is the built-in's name or the file's stem, or "name"."""
        is_object = isinstance(value, dict)
        fields = dict(self.r.object(value, key, MOTION_KEYS)) if is_object else {}
        where = child(key, "motion") if is_object else key
        text = self.r.string(fields.pop("motion", None) if is_object else value, where)
        motions = self.motion_sources(text, where, allow_glob)
        if "name" in fields:
            if len(motions) > 1:
                self.r.fail(child(key, "name"), f"a name for a glob matching {len(motions)} "
                                                "files; the files' stems name them")
            motions = [(self.r.name(fields.pop("name"), child(key, "name")), motions[0][1])]
        return [Part(name, {**fields, "motion": motion}, key, plain=not is_object)
                for name, motion in motions]

    def motion_sources(self, text, key, allow_glob):
        """[(name, motion)] of a motion string: a built-in, a file, or each file of a glob."""
        if text.startswith("builtin:"):
            name, known = text[len("builtin:"):], flsh.builtin_motion_names()
            if name not in known:
                self.r.fail(key, f"unknown built-in motion '{text}' (known: builtin:"
                                 f"{', builtin:'.join(known)})")
            return [(name, text)]
        files = self.files(text, key, "motion file", allow_glob)
        return [(id_part(Path(p).stem), p) for p in files]

    def files(self, text, key, what, allow_glob=True):
        """The files of a path string (resolved as self.path): the file, which must exist, or
        (allow_glob) each file a glob matches, sorted, at least one. `what` names the file in
        the message ("motion file not found: …")."""
        if allow_glob and re.search(r"[*?[]", text):
            files = sorted(p for p in glob.glob(self.path(text)) if os.path.isfile(p))
            if not files:
                self.r.fail(key, f"matches no file: {self.path(text)}")
            return files
        path = self.path(text)
        if not os.path.isfile(path):
            self.r.fail(key, f"{what} not found: {path}")
        return [path]

    def simulation(self, value, key, default_name=""):
        """A simulation entry: "skeleton", "fem", "rom" or {"simulation": ..., "name", and
        the scene format's avatar keys of that model: resolution, materials, basis,
        vibration_modes, modal_columns, handles, elastic_cubature, inertial_cubature,
        surface_partition_of_unity, options}. Named
        by the model or "name" (default_name is not used)."""
        fields = dict(self.r.object(value, key, SIMULATION_KEYS)) if isinstance(value, dict) \
            else {"simulation": value}
        where = child(key, "simulation") if isinstance(value, dict) else key
        kind = self.r.choice(fields.get("simulation"), where, SIMULATIONS)
        name = self.r.name(fields.pop("name", kind), child(key, "name"))
        if "materials" in fields:
            fields["materials"] = self.path(self.r.string(fields["materials"],
                                                          child(key, "materials")))
        return [Part(name, fields, key, plain=not isinstance(value, dict))]

    def variant(self, value, key, default_name):
        """A scene variant: {"name", and scene keys} laid over the spec's "scene"."""
        read_scene_settings(self.r, value, key, extra_keys=("name",))
        name = self.r.name(value.get("name", default_name), child(key, "name"))
        return [Part(name, {k: v for k, v in value.items() if k != "name"}, key)]

    # --- "jobs" ---------------------------------------------------------------------------
    def listed(self, value, key):
        """Jobs given one by one: {"name", "avatar", "motion", "simulation", "scene"}."""
        jobs = []
        for i, item in enumerate(self.r.list(value, key, 1)):
            where = child(key, i)
            self.r.object(item, where, JOB_KEYS)
            job_id = self.r.name(item.get("name", f"job{i}"), child(where, "name"))
            avatar = self.avatar(item.get("avatar", {}), child(where, "avatar"), "avatar")[0]
            motion = (self.motion(item["motion"], child(where, "motion"))[0]
                      if "motion" in item else Part("", {}, child(where, "motion")))
            simulation = self.simulation(item.get("simulation", "skeleton"),
                                         child(where, "simulation"))[0]
            scene = item.get("scene", {})
            read_scene_settings(self.r, scene, child(where, "scene"))
            variant = Part("", scene, child(where, "scene"))
            jobs.append(self.job(job_id, child(where, "name"), avatar, motion, simulation,
                                 variant))
        return jobs

    # --- one job --------------------------------------------------------------------------
    def job(self, job_id, id_origin, avatar, motion, simulation, variant):
        """The Job of one avatar, motion, simulation and scene variant."""
        scene = dict(self.common)
        for k, v in variant.fields.items():
            merge = k in MERGED_SCENE_KEYS and isinstance(v, dict)
            scene[k] = {**scene.get(k, {}), **v} if merge else v
        outputs = {**DEFAULT_OUTPUTS, **scene.get("outputs", {})}
        keep_states = outputs["npz"]
        outputs["npz"] = True  # data.npz is read off states.npz
        origin = {"id": id_origin, "": "scene"}
        for k in SCENE_KEYS:
            origin[k] = child(variant.origin, k) if k in variant.fields else child("scene", k)
        entry = {}
        for part in (avatar, motion, simulation):
            entry.update(part.fields)
            for k in part.fields:
                origin[f"avatars[0].{k}"] = part.origin if part.plain else child(part.origin, k)
        origin["avatars[0]"] = avatar.origin
        scene.update(avatars=[entry], outputs=outputs, cache_dir=self.cache_dir)
        return Job(id=job_id, scene=scene, avatar=avatar.name, simulation=entry["simulation"],
                   motion=entry.get("motion", ""), keep_states=keep_states, origin=origin,
                   **self.settings)

    # --- paths ----------------------------------------------------------------------------
    def path(self, text):
        """`text` resolved against the spec file's folder, absolute and normalized."""
        p = Path(os.path.expanduser(text))
        return os.path.normpath(str(p if p.is_absolute() else self.spec_dir / p))

    def model_path(self, value, key):
        """A body model: "synthetic" or an SMPL .npz file ("{gender}" is filled by flsh)."""
        text = self.r.string(value, key)
        if text == "synthetic":
            return text
        path = self.path(text)
        if "{gender}" not in path and not os.path.isfile(path):
            self.r.fail(key, f"body model file not found: {path}")
        return path
