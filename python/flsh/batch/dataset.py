"""flsh.batch.Dataset: a torch.utils.data.Dataset over the data set a batch wrote (its
index.json). This module imports torch; `import flsh.batch` does not (flsh.batch.Dataset
imports this module on first use)."""
import bisect

import numpy as np
import torch

from .data import PER_CLIP, PER_FRAME
from .index import load_clip, read_index

DEFAULT_FIELDS = ("vertices", "joints", "displacements")


class Dataset(torch.utils.data.Dataset):
    """The frames (item="frame", the default) or the clips (item="clip") of the done jobs of
    the output folder `out_dir`, in the index's order.

    A frame item is a dict of tensors: each of `fields` at that frame (vertices (V, 3),
    joints (24, 3), displacements (V, 3), poses (72,), trans (3,), times ()) or whole for
    the per-clip fields (betas (K,), faces (F, 3)), plus "clip" (the job's position in
    `self.jobs`) and "frame". A clip item holds the (T, ...) arrays. Tensors keep data.npz's
    dtype (float32 unless the spec's data_dtype is "float64"). Clips with different vertex
    counts cannot share a batch of the default collate function."""

    def __init__(self, out_dir, item="frame", fields=DEFAULT_FIELDS):
        if item not in ("frame", "clip"):
            raise ValueError(f"item: expected 'frame' or 'clip', got {item!r}")
        unknown = [f for f in fields if f not in PER_FRAME + PER_CLIP]
        if unknown:
            raise ValueError(f"fields: unknown {unknown} "
                             f"(known: {', '.join(PER_FRAME + PER_CLIP)})")
        self.out_dir = out_dir
        self.item = item
        self.fields = tuple(fields)
        self.jobs = read_index(out_dir)["jobs"]
        self._starts = np.cumsum([0] + [job["frames"] for job in self.jobs]).tolist()
        self._cached = (None, None)  # (clip index, arrays): frames come clip by clip

    def __len__(self):
        return len(self.jobs) if self.item == "clip" else self._starts[-1]

    def clip(self, index):
        """The numpy arrays of clip `index` (the last one read is kept)."""
        if self._cached[0] != index:
            self._cached = (index, load_clip(self.out_dir, self.jobs[index], self.fields))
        return self._cached[1]

    def __getitem__(self, index):
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} {self.item}s")
        if self.item == "clip":
            arrays = self.clip(index)
            return {"clip": index, **{k: torch.from_numpy(v.copy()) for k, v in arrays.items()}}
        clip = bisect.bisect_right(self._starts, index) - 1
        frame = index - self._starts[clip]
        arrays = self.clip(clip)
        item = {k: torch.from_numpy(np.array(v[frame] if k in PER_FRAME else v))  # a copy
                for k, v in arrays.items()}
        return {"clip": clip, "frame": frame, **item}
