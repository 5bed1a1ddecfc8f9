"""flsh: differentiable physics of SMPL human bodies.

The C++ core is the extension module ``flsh._flsh``; this package re-exports its public
names. Lengths are in metres, angles in radians, arrays are numpy float64 unless stated.

    import flsh
    model = flsh.make_synthetic_body(vertices=6890)
    posed = flsh.pose_body(model, betas=np.zeros(10), pose=np.zeros(72))
    posed.vertices  # (6890, 3)
"""
from . import _flsh
from ._flsh import (  # noqa: F401  (re-exports)
    NUM_JOINTS,
    SMPL_JOINT_NAMES,
    SMPL_PARENTS,
    SYNTHETIC_SHAPE_NAMES,
    BodyModel,
    Image,
    Motion,
    PosedBatch,
    PosedBody,
    RenderOptions,
    SyntheticBodyOptions,
    builtin_motion_names,
    left_jacobian_inverse_so3,
    left_jacobian_so3,
    load_body_model,
    load_motion,
    load_or_make_motion,
    log_so3,
    make_builtin_motion,
    make_synthetic_body,
    pose_body,
    pose_body_batch,
    read_mesh,
    read_png,
    render_mesh,
    render_sheet,
    rodrigues,
    save_body_model,
    save_motion,
    shaped_vertices,
    skew,
    slerp_rotation_vector,
    smpl_joint_index,
    to_smpl_pose,
    write_obj,
    write_ply,
    write_png,
)

# Same as project(flsh VERSION ...) in the top-level CMakeLists.txt (a test checks it).
__version__ = "0.1.0"

__all__ = [
    "NUM_JOINTS",
    "SMPL_JOINT_NAMES",
    "SMPL_PARENTS",
    "SYNTHETIC_SHAPE_NAMES",
    "BodyModel",
    "Image",
    "Motion",
    "PosedBatch",
    "PosedBody",
    "RenderOptions",
    "SyntheticBodyOptions",
    "builtin_motion_names",
    "left_jacobian_inverse_so3",
    "left_jacobian_so3",
    "load_body_model",
    "load_motion",
    "load_or_make_motion",
    "log_so3",
    "make_builtin_motion",
    "make_synthetic_body",
    "pose_body",
    "pose_body_batch",
    "read_mesh",
    "read_png",
    "render_mesh",
    "render_sheet",
    "rodrigues",
    "save_body_model",
    "save_motion",
    "shaped_vertices",
    "skew",
    "slerp_rotation_vector",
    "smpl_joint_index",
    "to_smpl_pose",
    "write_obj",
    "write_ply",
    "write_png",
    "__version__",
]
