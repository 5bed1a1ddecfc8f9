"""A job's data.npz: the per-frame arrays of the data set, read off flsh's states.npz.

    times          (T,)        float64     s
    vertices       (T, V, 3)   data_dtype  simulated surface, m (world; soft tissue included)
    joints         (T, 24, 3)  data_dtype  simulated joint centres t_b, m
    displacements  (T, V, 3)   data_dtype  soft-tissue displacement u of each surface vertex,
                                           m, unposed (rest) space; zeros for "skeleton"
    poses          (T, 72)     data_dtype  SMPL pose read off the state, rad
    trans          (T, 3)      data_dtype  SMPL root translation, m
    betas          (K,)        float64     shape used
    faces          (F, 3)      int32       triangles

data_dtype is the spec's (float32 by default). states.npz holds the soft-tissue state per tet
node (FEM) or per handle (ROM), not per surface vertex: the displacements are computed by
loading the job's scene again (its avatar comes from the cache) and reading
Simulable.get_soft_tissue_displacements() after set_state() of each saved frame, which
equals, bit for bit, reading it while stepping."""
import json

import numpy as np

import flsh

PER_FRAME = ("times", "vertices", "joints", "displacements", "poses", "trans")
PER_CLIP = ("betas", "faces")


def frame_arrays(scene_path, states_path, avatar, simulation, dtype="float32"):
    """The data.npz arrays of the job whose scene file is `scene_path` and whose flsh run
    wrote `states_path`; `avatar` is the avatar's name in the scene."""
    with np.load(states_path) as states:
        get = lambda key: states[f"{avatar}_{key}"]  # noqa: E731
        arrays = {
            "times": states["times"],
            "vertices": get("vertices").astype(dtype),
            "joints": get("joints").astype(dtype),
            "poses": get("poses").astype(dtype),
            "trans": get("trans").astype(dtype),
            "betas": get("betas"),
            "faces": get("faces").astype(np.int32),
        }
        if simulation == "skeleton":
            arrays["displacements"] = np.zeros_like(arrays["vertices"])
        else:
            arrays["displacements"] = soft_tissue_displacements(
                scene_path, get("states"), avatar).astype(dtype)
    return arrays


def soft_tissue_displacements(scene_path, states, avatar):
    """(T, V, 3) float64 soft-tissue displacements of the surface vertices of `avatar` for
    each state of `states` (T, numDofs)."""
    scene = flsh.load_scene(str(scene_path), verbose=False)
    with open(scene_path) as f:
        names = [a["name"] for a in json.load(f)["avatars"]]
    simulable = scene.simulables[names.index(avatar)]
    frames = []
    for state in states:
        simulable.set_state(state)
        frames.append(simulable.get_soft_tissue_displacements())
    return np.stack(frames)

