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

data_dtype is the spec's (float32 by default). All of it is read off the job's states.npz
(the soft avatars' `<avatar>_displacements` are flsh's per-vertex soft-tissue displacements,
Simulable.get_soft_tissue_displacements() of each saved frame)."""
import numpy as np

PER_FRAME = ("times", "vertices", "joints", "displacements", "poses", "trans")
PER_CLIP = ("betas", "faces")


def frame_arrays(states_path, avatar, simulation, dtype="float32"):
    """The data.npz arrays of the job whose flsh run wrote `states_path`; `avatar` is the
    avatar's name in the scene."""
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
            arrays["displacements"] = get("displacements").astype(dtype)
    return arrays
