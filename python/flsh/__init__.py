"""flsh: differentiable physics of SMPL human bodies."""
from . import _flsh  # noqa: F401
