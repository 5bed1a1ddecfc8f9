"""flsh.torch: flsh's differentiable pieces as torch.autograd Functions.

``smpl(model, betas, pose, trans)`` is the SMPL forward pass of flsh's C++ core (ARCHITECTURE.md
§2) with a backward pass from its analytic Jacobians (PosedBodyJacobians), not from tracing:

    import torch, flsh, flsh.torch
    model = flsh.make_synthetic_body(vertices=6890)
    pose = torch.zeros(72, dtype=torch.float64, requires_grad=True)
    vertices, joints = flsh.torch.smpl(model, torch.zeros(10, dtype=torch.float64), pose)
    joints[7].sum().backward()  # pose.grad: (72,)

``simulate(simulator, betas=…, pose_targets=…, …)`` is a whole simulated rollout (flsh.Rollout,
docs/adjoint.md) as an autograd Function: joint (and optionally vertex) trajectories as
functions of β, per-step pose and root targets, the 4 stiffnesses, the initial state and
velocity and, for the soft models (model="fem" or "rom"), the material file's coefficients
(material=), with a backward pass by the adjoint method:

    sim = flsh.torch.RolloutSimulator(model, flsh.make_builtin_motion("walk"), steps=8,
                                      colliders=[flsh.Collider.plane()])
    betas = torch.zeros(10, dtype=torch.float64, requires_grad=True)
    joints = flsh.torch.simulate(sim, betas=betas)       # (8, 24, 3)
    joints[-1, 0, 1].backward()                          # betas.grad: (10,)

``point_to_surface(points, vertices, faces)`` is the squared distance of unordered points (a
scan) to the simulated surface, differentiable in the vertices: the loss of a fit to scans
without known correspondences (flsh/surface_distance.py).

Tensors are float64 on the CPU. Lengths in m, angles in rad. The model is immutable and never
changed; inputs are never modified in place; every simulate() call builds its own avatar and
simulable. Import it as ``flsh.torch`` (``import flsh`` does not import torch).
"""
from __future__ import annotations

import numpy as np
import torch
from torch.autograd.function import once_differentiable

from . import _flsh
from .surface_distance import point_to_surface  # noqa: F401  (re-export)

__all__ = ["RolloutFunction", "RolloutSimulator", "SmplFunction", "simulate", "smpl"]

_POSE_SIZE = 72


def _check_float64_cpu(value, name: str, expected: str) -> None:
    """ValueError unless `value` is a float64 CPU tensor (`expected` names the wanted shape)."""
    if not isinstance(value, torch.Tensor):
        raise ValueError(f"{name}: expected a torch.Tensor of shape {expected} and dtype "
                         f"torch.float64, got {type(value).__name__}")
    if value.dtype != torch.float64:
        raise ValueError(f"{name}: expected dtype torch.float64, got {value.dtype} "
                         f"(convert with .double())")
    if value.device.type != "cpu":
        raise ValueError(f"{name}: expected a CPU tensor, got device {value.device}")


def _check_tensor(value, name: str, last: int | None, expected: str) -> torch.Tensor:
    """`value` as a float64 CPU tensor of shape (last,) or (B, last); ValueError otherwise."""
    _check_float64_cpu(value, name, expected)
    if value.dim() not in (1, 2) or (last is not None and value.shape[-1] != last):
        raise ValueError(f"{name}: expected shape {expected}, got {tuple(value.shape)}")
    return value


class SmplFunction(torch.autograd.Function):
    """Batched SMPL forward pass: (betas (B, K'), pose (B, 72), trans (B, 3)) -> vertices
    (B, V, 3), joints (B, 24, 3). Use :func:`smpl`, which checks and broadcasts the inputs."""

    @staticmethod
    def forward(ctx, model, betas, pose, trans):
        need_jacobians = any(ctx.needs_input_grad[1:4])
        betas_np = betas.detach().numpy()
        pose_np = pose.detach().numpy()
        trans_np = trans.detach().numpy()
        frames = pose_np.shape[0]
        vertices = np.empty((frames, model.num_vertices, 3))
        joints = np.empty((frames, 24, 3))
        jacobians = []
        for b in range(frames):
            posed = _flsh.pose_body(model, betas_np[b], pose_np[b], trans_np[b],
                                    jacobians=need_jacobians)
            vertices[b] = posed.vertices
            joints[b] = posed.joints
            if need_jacobians:
                jacobians.append((posed.vertices_betas, posed.vertices_pose,
                                  posed.joints_betas, posed.joints_pose))
        ctx.jacobians = jacobians
        ctx.num_betas = betas_np.shape[1]
        return torch.from_numpy(vertices), torch.from_numpy(joints)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_vertices, grad_joints):
        # dL/dp = Σ_points (dL/dx) · (dx/dp): contractions over (point, coordinate).
        K = ctx.num_betas
        grad_v = grad_vertices.detach().numpy()
        grad_j = grad_joints.detach().numpy()
        frames = grad_v.shape[0]
        grad_betas = np.zeros((frames, K))
        grad_pose = np.zeros((frames, _POSE_SIZE))
        for b, (v_betas, v_pose, j_betas, j_pose) in enumerate(ctx.jacobians):
            if K:
                grad_betas[b] = (np.tensordot(grad_v[b], v_betas[:, :, :K], axes=([0, 1], [0, 1]))
                                 + np.tensordot(grad_j[b], j_betas[:, :, :K], axes=([0, 1], [0, 1])))
            grad_pose[b] = (np.tensordot(grad_v[b], v_pose, axes=([0, 1], [0, 1]))
                            + np.tensordot(grad_j[b], j_pose, axes=([0, 1], [0, 1])))
        # d(x)/d(trans) is the identity for every vertex and joint.
        grad_trans = grad_v.sum(axis=1) + grad_j.sum(axis=1)
        return (None, torch.from_numpy(grad_betas), torch.from_numpy(grad_pose),
                torch.from_numpy(grad_trans))


def smpl(model, betas: torch.Tensor, pose: torch.Tensor, trans: torch.Tensor | None = None):
    """SMPL vertices and joints of flsh's forward pass, differentiable in betas, pose and trans.

    model: flsh.BodyModel (read only). betas: (K',) or (B, K') with K' ≤ model.num_betas (zero
    padded). pose: (72,) or (B, 72) axis-angle, rad (SMPL layout). trans: (3,) or (B, 3), m, or
    None (zero). All float64 CPU tensors; unbatched inputs are shared by every frame.

    Returns (vertices, joints): float64 tensors (V, 3) and (24, 3) in m, or (B, V, 3) and
    (B, 24, 3) if any input has a batch dimension. Gradients come from the analytic Jacobians
    (computed only when an input requires grad). ValueError on a wrong dtype, device or shape;
    TypeError if model is not a flsh.BodyModel.
    """
    if not isinstance(model, _flsh.BodyModel):
        raise TypeError(f"model: expected a flsh.BodyModel, got {type(model).__name__}")
    K = model.num_betas
    betas = _check_tensor(betas, "betas", None, f"(K',) or (B, K') with K' <= {K}")
    if betas.shape[-1] > K:
        raise ValueError(f"betas: expected at most {K} values (the model's shape components) in "
                         f"the last dimension, got shape {tuple(betas.shape)}")
    pose = _check_tensor(pose, "pose", _POSE_SIZE, "(72,) or (B, 72)")
    if trans is None:
        trans = torch.zeros(3, dtype=torch.float64)
    trans = _check_tensor(trans, "trans", 3, "(3,) or (B, 3)")

    batch_sizes = {t.shape[0] for t in (betas, pose, trans) if t.dim() == 2}
    if len(batch_sizes) > 1:
        raise ValueError("betas, pose, trans: batch sizes differ: "
                         f"{tuple(betas.shape)}, {tuple(pose.shape)}, {tuple(trans.shape)}")
    batched = bool(batch_sizes)
    frames = batch_sizes.pop() if batched else 1

    def frames_of(t):  # (B, n) views; expand's backward sums the gradients of shared inputs
        return t.expand(frames, -1) if t.dim() == 1 else t

    vertices, joints = SmplFunction.apply(model, frames_of(betas), frames_of(pose),
                                          frames_of(trans))
    if not batched:
        return vertices[0], joints[0]
    return vertices, joints


# ---------------------------------------------------------------------------------------------
# Differentiable rollouts

_NUM_STIFFNESSES = 4  # joint (N/m), tracking (1/s²), root (1/s²), contact (N/m³)


def _check_fixed(value, name: str, shape: tuple, expected: str) -> torch.Tensor:
    """`value` as a float64 CPU tensor of exactly `shape` (−1 = any extent); ValueError else."""
    _check_float64_cpu(value, name, expected)
    if value.dim() != len(shape) or any(e not in (-1, a) for e, a in zip(shape, value.shape)):
        raise ValueError(f"{name}: expected shape {expected}, got {tuple(value.shape)}")
    if not bool(torch.isfinite(value).all()):
        raise ValueError(f"{name}: contains NaN or Inf")
    return value


class RolloutSimulator:
    """What stays fixed across differentiable rollouts: body model, mocap, simulation options,
    colliders, Newton options and the number of steps T. Never changed by :func:`simulate`
    (treat it as read only); shared by any number of calls, each of which builds its own
    SoftAvatar and Simulable.

    body: flsh.BodyModel. mocap: flsh.Motion to track, or None (no tracking: a passive body
    starting in the rest pose). steps: T ≥ 1 (h = options.time_step, s). model: "skeleton"
    (24 rigid bones, the default), "fem" (bones and nodal soft tissue on a tet mesh) or "rom"
    (bones and the reduced soft tissue with its cubatures; its basis and cubature are part of
    the avatar, fixed during a rollout: the gradients are those of the reduced model). The soft
    models' states are the bones followed by their soft state (num_dofs), their vertices the
    simulated surface; their material coefficients are an input of simulate() (material=, see
    own_material and material_names); β reaches them through SoftAvatar.with_shape (the
    discretization is held, see simulate). resolution: interior node density of the tet mesh (soft models);
    cache_dir: where soft avatars are cached (None: $FLSH_CACHE_DIR or ~/.cache/flsh);
    avatar_settings: further flsh.SoftAvatar keyword arguments (e.g. basis, vibration_modes,
    handles, elastic_cubature_points, material_file). options:
    flsh.SimulableOptions or None. colliders: flsh.Collider list (e.g. a ground plane). newton:
    flsh.NewtonOptions of the model's steps, or None; the gradients are exact for the converged
    steps, so the default is tight: the skeleton's gradient_tolerance 1e-11 (central differences
    of the joints then agree with the gradients to ~5e-10 on a 600-vertex body), the soft
    models' 1e-10 on the scene's settings for them. betas: (≤K,) numpy shape used when simulate() gets betas=None
    (default zeros). density (kg/m³) and voxel_size (m): SoftAvatar settings.

    The default-shape avatar is built once and kept: it also keeps the voxelized template
    alive, which every new avatar of the same body and settings reuses.
    """

    MODELS = ("skeleton", "fem", "rom")

    def __init__(self, body, mocap=None, *, steps: int, model: str = "skeleton", options=None,
                 colliders=(), newton=None, betas=None, density: float = 1010.0,
                 voxel_size: float = 0.01, resolution: float = 1.0, cache_dir=None,
                 avatar_settings: dict | None = None):
        if avatar_settings is not None and not isinstance(avatar_settings, dict):
            raise TypeError(f"avatar_settings: expected a dict of SoftAvatar keyword arguments "
                            f"or None, got {type(avatar_settings).__name__}")
        self._configure(body, mocap, steps, model, options, colliders, newton)
        self.density = float(density)
        self.voxel_size = float(voxel_size)
        self.resolution = float(resolution)
        self.cache_dir = cache_dir
        self.avatar_settings = dict(avatar_settings or {})
        self.scene_source = None  # from_scene's file and avatar
        self.avatar_name = None
        default_betas = np.zeros(body.num_betas) if betas is None else np.asarray(betas, float)
        self._set_default_avatar(self._make_avatar(default_betas))

    @classmethod
    def from_scene(cls, path=None, *, avatar=0, steps: int | None = None, newton=None,
                   duration: float = 0.0, time_step: float = 0.0, verbose: bool = False):
        """The simulator of one avatar of a scene file (None: the built-in default scene), built
        as `flsh simulate` builds it: its body, motion (placed by offset and yaw), shape,
        simulation model and settings (resolution, materials, ROM basis and cubatures, the
        avatar cache), SimulableOptions (time step included) and the scene's colliders with its
        "ground". avatar: index or name in the file's "avatars" (the others are not simulated,
        and avatar–avatar contact is off). steps: T (None: duration / time_step). newton: as in
        the constructor (None: tight). duration, time_step: overrides (0 = the file's).
        ValueError / OSError on a bad file, an unknown avatar or steps < 1."""
        scene = _flsh.load_scene_avatars(path, duration=duration, time_step=time_step,
                                         verbose=verbose)
        parts = scene["avatars"]
        names = [p["name"] for p in parts]
        if isinstance(avatar, str):
            if avatar not in names:
                raise ValueError(f"avatar: no avatar named {avatar!r} in {scene['spec'].source} "
                                 f"(avatars: {', '.join(names)})")
            part = parts[names.index(avatar)]
        elif isinstance(avatar, (int, np.integer)) and not isinstance(avatar, bool):
            if not 0 <= avatar < len(parts):
                raise ValueError(f"avatar: expected an index in [0, {len(parts)}) into "
                                 f"{scene['spec'].source}'s avatars, got {avatar}")
            part = parts[avatar]
        else:
            raise TypeError(f"avatar: expected an index or a name, got {type(avatar).__name__}")
        if steps is None:
            steps = scene["steps"]
        self = cls.__new__(cls)
        self._configure(part["body"], part["motion"], steps, part["simulation"],
                        part["simulable"].options, scene["colliders"], newton)
        spec = next(a for a in scene["spec"].avatars if a.name == part["name"])
        self.density = None  # the avatar's own settings (the scene file's)
        self.voxel_size = None
        self.resolution = float(spec.resolution)
        self.cache_dir = None
        self.avatar_settings = {}
        self.scene_source = scene["spec"].source
        self.avatar_name = part["name"]
        self._set_default_avatar(part["avatar"])
        return self

    def _configure(self, body, mocap, steps, model, options, colliders, newton):
        """Checks and keeps the settings every rollout shares."""
        if not isinstance(body, _flsh.BodyModel):
            raise TypeError(f"body: expected a flsh.BodyModel, got {type(body).__name__}")
        if mocap is not None and not isinstance(mocap, _flsh.Motion):
            raise TypeError(f"mocap: expected a flsh.Motion or None, got {type(mocap).__name__}")
        if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
            raise ValueError(f"steps: expected an integer ≥ 1, got {steps!r}")
        if model not in self.MODELS:
            raise ValueError(f"model: expected one of {', '.join(self.MODELS)}, got {model!r}")
        if options is not None and not isinstance(options, _flsh.SimulableOptions):
            raise TypeError(f"options: expected a flsh.SimulableOptions or None, got "
                            f"{type(options).__name__}")
        colliders = list(colliders)
        for i, c in enumerate(colliders):
            if not isinstance(c, _flsh.Collider):
                raise TypeError(f"colliders[{i}]: expected a flsh.Collider, got {type(c).__name__}")
        if newton is not None and not isinstance(newton, _flsh.NewtonOptions):
            raise TypeError(f"newton: expected a flsh.NewtonOptions or None, got "
                            f"{type(newton).__name__}")
        self.body = body
        self.mocap = mocap
        self.steps = int(steps)
        self.options = options if options is not None else _flsh.SimulableOptions()
        self.colliders = tuple(colliders)
        # The model's Newton settings; by default tight (the gradients are exact for the
        # converged steps): the skeleton's at 1e-11, the soft models' (the scene's lagged-factor
        # Newton on CHOLMOD, or the ROM's) at 1e-10.
        rollout_options = _flsh.RolloutOptions()
        if model == "skeleton":
            rollout_options.newton = newton or _flsh.NewtonOptions(gradient_tolerance=1e-11,
                                                                   max_iterations=50)
        else:
            name = "soft_tissue_newton" if model == "fem" else "reduced_newton"
            if newton is None:
                newton = getattr(rollout_options, name)
                newton.gradient_tolerance = 1e-10
                newton.max_iterations = 100
            setattr(rollout_options, name, newton)
        self.rollout_options = rollout_options
        self.model = model

    def _set_default_avatar(self, avatar):
        self._default_avatar = avatar
        self.num_dofs = _flsh.Simulable(avatar, self.mocap, self.options).num_dofs

    @property
    def num_betas(self) -> int:
        return self.body.num_betas

    @property
    def num_vertices(self) -> int:
        return self.body.num_vertices

    @property
    def default_betas(self) -> np.ndarray:
        """(K,) the shape simulate() uses when betas is None."""
        return self._default_avatar.betas

    @property
    def soft_tissue(self) -> bool:
        """Whether the model has soft tissue ("fem" or "rom")."""
        return self.model != "skeleton"

    def _make_avatar(self, betas: np.ndarray):
        avatar = _flsh.SoftAvatar(self.body, betas, density=self.density,
                                  voxel_size=self.voxel_size, resolution=self.resolution,
                                  cache_dir=self.cache_dir, **self.avatar_settings)
        if self.soft_tissue:
            avatar.enable_soft_tissue()
        if self.model == "rom":
            avatar.enable_reduced_model()
            avatar.enable_elastic_cubature()
            avatar.enable_inertial_cubature()
        avatar.init_volumetric_data()
        return avatar

    def material_names(self) -> list:
        """Names of the material vector's entries (soft models): '<key>.log_value' and
        '<key>.log_slopes[k]' per coefficient of the material file, <key> its key path (e.g.
        'layers.soft_tissue.E1'; docs/materials.md)."""
        self._require_soft("material_names")
        return list(self._default_avatar.material_parameter_names)

    def own_material(self) -> np.ndarray:
        """(P,) the avatar's material coefficients (soft models), P = 40·(1 + K): per
        coefficient a = log c₀ then its K log-slopes b (c(β) = exp(a + bᵀβ)); what simulate()
        uses for material=None."""
        self._require_soft("own_material")
        return self._default_avatar.material_parameters

    def _require_soft(self, who: str) -> None:
        if not self.soft_tissue:
            raise ValueError(f"{who}: the {self.model!r} model has no soft-tissue material; use "
                             f"model='fem' or 'rom'")

    def make_simulable(self, betas: np.ndarray | None = None,
                       material: np.ndarray | None = None):
        """A new flsh.Simulable with these settings and colliders, of shape `betas` (≤K,) or the
        default shape (None; then the avatar is the shared, immutable default one; otherwise
        the default avatar at `betas` with its discretization, SoftAvatar.with_shape), with the
        material coefficients `material` ((P,) as own_material(); None = the avatar's own: soft
        models only, SoftAvatar.with_material)."""
        # Another shape keeps the default avatar's discretization (SoftAvatar.with_shape: for
        # the soft models the tet mesh, bone nodes, frames and the ROM's basis; for the
        # skeleton the same as a new avatar), so that β's gradient is exact for what runs.
        avatar = self._default_avatar if betas is None else self._default_avatar.with_shape(betas)
        if material is not None:
            self._require_soft("material")
            avatar = avatar.with_material(material)
        simulable = _flsh.Simulable(avatar, self.mocap, self.options)
        if self.colliders:
            simulable.set_colliders(list(self.colliders))
        return simulable

    def rollout(self, betas: np.ndarray | None = None, material: np.ndarray | None = None,
                **inputs):
        """A new flsh.Rollout of T steps, already run: shape `betas` (numpy (≤K,) or None),
        material (numpy (P,) or None, soft models) and numpy inputs by the names of
        flsh.RolloutInputs (None = the simulable's own)."""
        rollout = _flsh.Rollout(self.make_simulable(betas, material), self.rollout_options)
        rollout.run(self.steps, _flsh.RolloutInputs(**inputs))
        return rollout

    def own_inputs(self, betas: np.ndarray | None = None) -> dict:
        """The simulable's own values of every rollout input, as numpy arrays keyed by the
        simulate() argument names: what simulate() uses for None (a start for optimizing them).
        pose_targets (T, 72) and root_targets (T, 3) are the mocap's at steps 1..T (absent
        without a mocap); stiffnesses (4,); initial_state and initial_velocity (numDofs,) as
        initialize() sets them for shape `betas` (None = the default shape)."""
        simulable = self.make_simulable(betas)
        simulable.initialize()
        values = {"stiffnesses": simulable.get_parameter(_flsh.SimParameter.Stiffnesses),
                  "initial_state": simulable.get_state(),
                  "initial_velocity": simulable.get_velocity()}
        if self.mocap is not None:
            root_joint = simulable.get_parameter(_flsh.SimParameter.RestJoints)[:3]
            pose = np.empty((self.steps, 72))
            root = np.empty((self.steps, 3))
            for t in range(self.steps):
                simulable.pre_update()  # the targets of step t + 1 (they depend on time only)
                pose[t] = simulable.get_parameter(_flsh.SimParameter.PoseTargets)
                root[t] = (simulable.get_parameter(_flsh.SimParameter.RootTranslationTarget)
                           - root_joint)
                simulable.post_update()
            values["pose_targets"] = pose
            values["root_targets"] = root
        return values

    def __repr__(self):
        return (f"RolloutSimulator(model={self.model!r}, vertices={self.num_vertices}, "
                f"steps={self.steps}, "
                f"mocap={'yes' if self.mocap is not None else 'none'}, "
                f"colliders={len(self.colliders)})")


# Names of the tensor inputs of RolloutFunction, in argument order, and their RolloutInputs /
# RolloutVariables member (betas: the `shape` gradient; the avatar is built from them).
_ROLLOUT_INPUTS = ("pose_targets", "root_targets", "stiffnesses", "initial_state",
                   "initial_velocity")


class RolloutFunction(torch.autograd.Function):
    """One simulated rollout: (betas, material, pose_targets, root_targets, stiffnesses,
    initial_state, initial_velocity), each a float64 tensor or None (= the simulable's own) ->
    joints (T, 24, 3) and vertices (T, V, 3) (empty (T, 0, 3) unless requested). Use
    :func:`simulate`, which checks the inputs."""

    @staticmethod
    def forward(ctx, simulator, want_vertices, betas, material, pose_targets, root_targets,
                stiffnesses, initial_state, initial_velocity):
        tensors = (pose_targets, root_targets, stiffnesses, initial_state, initial_velocity)
        inputs = {name: t.detach().numpy() for name, t in zip(_ROLLOUT_INPUTS, tensors)
                  if t is not None}
        betas_np = None if betas is None else betas.detach().numpy()
        material_np = None if material is None else material.detach().numpy()
        rollout = simulator.rollout(betas_np, material_np, **inputs)
        joints = torch.from_numpy(rollout.joints())
        if want_vertices:
            vertices = torch.from_numpy(rollout.vertex_trajectory())
        else:
            vertices = torch.empty((simulator.steps, 0, 3), dtype=torch.float64)
            ctx.mark_non_differentiable(vertices)
        ctx.rollout = rollout if any(ctx.needs_input_grad[2:]) else None
        ctx.want_vertices = want_vertices
        ctx.num_betas = 0 if betas is None else betas.shape[0]
        return joints, vertices

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_joints, grad_vertices):
        rollout = ctx.rollout
        grad_v = grad_vertices.detach().numpy() if ctx.want_vertices else None
        states_cotangent, direct = rollout.trajectory_cotangent(
            grad_joints.detach().numpy(), grad_v)
        needs = ctx.needs_input_grad
        # Only the groups asked for (β and the material are the costly ones).
        groups = [name for name, needed in zip(
            ("shape", "material", "pose_targets", "root_targets", "stiffnesses"), needs[2:7])
            if needed]
        grad = rollout.backward(states_cotangent, direct, groups or ["stiffnesses"])

        def as_tensor(needed, values):
            return torch.from_numpy(values) if needed and values is not None else None

        grad_betas = None
        if needs[2] and grad.shape is not None:  # (K,): the padded components are dropped
            grad_betas = torch.from_numpy(grad.shape[:ctx.num_betas].copy())
        return (None, None, grad_betas, as_tensor(needs[3], grad.material),
                as_tensor(needs[4], grad.pose_targets), as_tensor(needs[5], grad.root_targets),
                as_tensor(needs[6], grad.stiffnesses), as_tensor(needs[7], grad.initial_state),
                as_tensor(needs[8], grad.initial_velocity))


def simulate(simulator: RolloutSimulator, betas: torch.Tensor | None = None,
             pose_targets: torch.Tensor | None = None, root_targets: torch.Tensor | None = None,
             stiffnesses: torch.Tensor | None = None, initial_state: torch.Tensor | None = None,
             initial_velocity: torch.Tensor | None = None, *, material: torch.Tensor | None = None,
             vertices: bool = False):
    """Simulates simulator.steps steps and returns the joint trajectory, differentiable in every
    tensor input (adjoint method, flsh.Rollout).

    simulator: RolloutSimulator (body, mocap, options, colliders, T). Inputs, float64 CPU
    tensors or None (= the simulable's own):
      betas (K',) body shape, K' ≤ K (zero padded): the default avatar at β with its
        discretization kept (SoftAvatar.with_shape: for the soft models the tet mesh, bone
        nodes and frames, and the ROM's basis and cubatures);
      material (P,) the soft models' material coefficients (RolloutSimulator.own_material,
        material_names: log-values and log-slopes of the material file), P = 40·(1 + K); the
        avatar's discretization is kept (SoftAvatar.with_material);
      pose_targets (T, 72) tracking target rotation vectors per step, rad (SMPL layout: bone
        b ≥ 1 relative to its parent, the root global); None = the mocap's;
      root_targets (T, 3) SMPL trans per step, m (root joint target J_0(β) + trans);
      stiffnesses (4,) joint (N/m), tracking (1/s²), root (1/s²), contact (N/m³);
      initial_state (numDofs,) per bone [t_b m, rotation vector r_b rad] (Simulable.get_state);
      initial_velocity (numDofs,) per DoF, m/s and world-frame rad/s (Simulable.set_velocity).
    Targets need a mocap (the simulable tracks only then).

    Returns joints (T, 24, 3), the bone positions t_b after steps 1..T (m); with vertices=True
    (joints, vertices) with the vertices (T, V, 3) (m): the SMPL vertices (skeleton; a skinning
    per step forward and an SMPL Jacobian per step backward) or the simulated surface (soft
    models). ValueError on a wrong dtype, device, shape or a non-finite value; TypeError if
    simulator is not a RolloutSimulator.
    """
    if not isinstance(simulator, RolloutSimulator):
        raise TypeError(f"simulator: expected a flsh.torch.RolloutSimulator, got "
                        f"{type(simulator).__name__}")
    T, K, n = simulator.steps, simulator.num_betas, simulator.num_dofs
    if betas is not None:
        _check_fixed(betas, "betas", (-1,), f"(K',) with K' <= {K}")
        if betas.shape[0] > K:
            raise ValueError(f"betas: expected at most {K} values (the model's shape "
                             f"components), got shape {tuple(betas.shape)}")
    expected = {"pose_targets": ((T, 72), f"(T, 72) = ({T}, 72)"),
                "root_targets": ((T, 3), f"(T, 3) = ({T}, 3)"),
                "stiffnesses": ((_NUM_STIFFNESSES,), f"({_NUM_STIFFNESSES},)"),
                "initial_state": ((n,), f"(numDofs,) = ({n},)"),
                "initial_velocity": ((n,), f"(numDofs,) = ({n},)")}
    given = {"pose_targets": pose_targets, "root_targets": root_targets,
             "stiffnesses": stiffnesses, "initial_state": initial_state,
             "initial_velocity": initial_velocity}
    for name, value in given.items():
        if value is not None:
            _check_fixed(value, name, *expected[name])
    if material is not None:
        simulator._require_soft("material")
        P = len(simulator.own_material())
        _check_fixed(material, "material", (P,), f"(P,) = ({P},)")
    if simulator.mocap is None and (pose_targets is not None or root_targets is not None):
        raise ValueError("pose_targets, root_targets: the simulator has no mocap, so its "
                         "simulable does not track targets")
    joints, vertex_trajectory = RolloutFunction.apply(
        simulator, bool(vertices), betas, material, pose_targets, root_targets, stiffnesses,
        initial_state, initial_velocity)
    return (joints, vertex_trajectory) if vertices else joints
