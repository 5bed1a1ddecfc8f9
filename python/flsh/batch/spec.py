"""What a batch spec becomes: Jobs (one complete scene each, with its spec hash) in a Plan;
and the scene settings every job shares (docs/batch.md gives the format)."""
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from .checks import child

SCENE_KEYS = ("time_step", "duration", "avatar_contact", "newton", "colliders", "ground",
              "outputs")
OUTPUT_KEYS = ("ply", "npz", "gltf", "png", "png_frames", "every")
# flsh.batch writes a data set: states.npz yes, the heavier files for looking at a run no.
DEFAULT_OUTPUTS = {"ply": False, "npz": True, "gltf": False, "png": False}


def canonical_json(value):
    """The canonical text of a JSON value: sorted keys, no spaces, shortest exact floats."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=True,
                      allow_nan=False)


@dataclass
class Job:
    """One simulation of the batch: one avatar, one motion, one simulation model, one scene.

    `scene` is the scene file's content as written into the job folder (absolute paths,
    cache_dir set, outputs without "dir", outputs.npz always true because data.npz is made
    from states.npz; `keep_states` is the spec's outputs.npz). `origin` maps each avatar key
    and scene key to the spec key it came from (for error messages); it is not hashed."""
    id: str
    scene: dict
    avatar: str
    simulation: str
    motion: str
    keep_states: bool = True
    max_unconverged_steps: object = None  # int, or None: no limit
    data_dtype: str = "float32"
    # A fitting job (spec "fits"): its settings (betas, material, iterations, noise) with the
    # scan file's absolute path ("scans") and the sha256 of its content ("scans_sha256");
    # None for a simulation job.
    fit: object = None
    origin: dict = field(default_factory=dict, compare=False)

    @property
    def kind(self):
        """"simulate" (a flsh.run_scene of the scene) or "fit" (flsh.fitting.fit_scans)."""
        return "simulate" if self.fit is None else "fit"

    def content(self):
        """What the spec hash covers: everything that changes the job's outputs or status;
        not the id, not the cache folder (moving the cache redoes nothing). A fitting job's
        covers its scan file's content (an edited scan file is fitted again)."""
        scene = {k: v for k, v in self.scene.items() if k != "cache_dir"}
        content = {"scene": scene, "keep_states": self.keep_states,
                   "max_unconverged_steps": self.max_unconverged_steps,
                   "data_dtype": self.data_dtype}
        if self.fit is not None:
            content["fit"] = self.fit
        return content

    @property
    def spec_hash(self):
        """sha256 (hex) of the canonical JSON of content()."""
        return hashlib.sha256(canonical_json(self.content()).encode()).hexdigest()


@dataclass
class Plan:
    """A checked spec: where the outputs and the avatar cache go, and every job in order."""
    spec_path: Path
    out_dir: Path
    cache_dir: Path
    jobs: list


def read_scene_settings(reader, value, key, extra_keys=()):
    """A scene-settings object (the top-level keys of a scene file but avatars, cache_dir and
    use_cache); its outputs are checked here (flsh checks the rest, scene_check.py)."""
    reader.object(value, key, extra_keys + SCENE_KEYS)
    if "outputs" in value:
        outputs = value["outputs"]
        if isinstance(outputs, dict) and "dir" in outputs:
            reader.fail(child(child(key, "outputs"), "dir"),
                        "set by flsh.batch (each job writes into its own folder); remove it")
        reader.object(outputs, child(key, "outputs"), OUTPUT_KEYS)
        for name in ("ply", "npz", "gltf", "png"):
            if name in outputs:
                reader.boolean(outputs[name], child(child(key, "outputs"), name))
    return value
