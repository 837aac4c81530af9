"""Optional rendering backend on ManiSkill3 (``pip install 'scapo[maniskill]'``): many views at once.

ManiSkill3 (Tao et al., "ManiSkill3: GPU parallelized robotics simulation and rendering", 2024) runs
``num_envs`` SAPIEN sub-scenes in one GPU simulation and renders all their cameras in one batch. This
backend puts the same articulated object in every sub-scene, each at its own joint state and with its own
camera pose, and renders ``num_envs`` views per call; on CPU (ManiSkill's CPU simulation, one sub-scene) it
renders one view per call and is how the tests compare it with the SAPIEN backend.

What it shares with :mod:`scapo.sim.render`: the draws (joint state and viewpoint from the same per-attempt
generator, :func:`~scapo.sim.render.sample_state` / :func:`~scapo.sim.render.sample_camera_pose`), the camera
(size, vertical field of view, near / far planes), the object frame (the root link at ``spec.T_obj_root``), and
everything after the pictures: :func:`~scapo.sim.render.process_frame` labels, samples and assembles the ground
truth from the ``Position`` and ``Segmentation`` pictures, rejecting views by the same rules. The parts' motions
come from the object's forward kinematics (:meth:`~scapo.sim.assets.urdf.ArticulationSpec.link_poses`, which the
SAPIEN backend's tests check against the simulator), so the ground truth is the SAPIEN backend's for the same
state and camera; the pictures agree to float rounding (the same shader, float positions), so farthest-point
sampling may pick a different point where two are equally far. Not supported here: the realistic sensor's
support plane (``SensorConfig.ground``).
"""

from __future__ import annotations

import contextlib
from collections import Counter
from pathlib import Path

import numpy as np

from scapo.errors import ConfigError, RejectedViewError, RenderError
from scapo.ops.rigid import invert_transform, sapien_camera_pose
from scapo.sim.assets.urdf import ArticulationSpec
from scapo.sim.render import (
    CameraConfig,
    Frame,
    RenderConfig,
    ViewConfig,
    _reason_key,
    _rejection_hint,
    part_link_names,
    process_frame,
    qpos_layout,
    sample_camera_pose,
    sample_state,
    segmentation_lut,
)


def available() -> bool:
    """Whether ManiSkill3 is installed."""
    try:
        import mani_skill  # noqa: F401
    except ImportError:
        return False
    return True


def _env_class(shader: str = "trivial"):
    """The ManiSkill environment class whose camera renders with SAPIEN shader folder ``shader`` (defined on first
    use, so that importing scapo never needs ManiSkill)."""
    import sapien
    from mani_skill.envs.sapien_env import BaseEnv
    from mani_skill.render.shaders import ShaderConfig
    from mani_skill.sensors.camera import CameraConfig as MSCameraConfig
    from mani_skill.utils.structs.pose import Pose
    from mani_skill.utils.structs.types import SimConfig

    # the RenderConfig's shader folder ("trivial" by default, as the SAPIEN backend), raw float pictures
    raw = ShaderConfig(shader_pack=shader,
                       texture_names={"Position": ["position"], "Segmentation": ["segmentation"]},
                       texture_transforms={"Position": lambda d: {"position": d},
                                           "Segmentation": lambda d: {"segmentation": d}})

    class ScapoViewsEnv(BaseEnv):
        """One articulated object per sub-scene and one camera; no robot, no task."""

        def __init__(self, *args, urdf: str, T_root: np.ndarray, camera: CameraConfig, **kwargs):
            self._urdf, self._T_root, self._cam = urdf, T_root, camera
            super().__init__(*args, **kwargs)

        @property
        def _default_sim_config(self):
            return SimConfig()

        @property
        def _default_sensor_configs(self):
            c = self._cam
            return [MSCameraConfig("scapo_camera", pose=sapien.Pose(), width=c.width, height=c.height,
                                   fov=np.radians(c.fovy_deg), near=c.near, far=c.far, shader_config=raw)]

        def _load_agent(self, options):
            pass

        def _load_scene(self, options):
            loader = self.scene.create_urdf_loader()
            loader.fix_root_link = True
            self.object = loader.load(self._urdf, name="scapo_object")
            self.object.set_root_pose(Pose.create(sapien.Pose(self._T_root)))

        def _initialize_episode(self, env_idx, options):
            pass

        def evaluate(self):
            return {}

        def _get_obs_extra(self, info):
            return {}

        def get_state_dict(self):  # no agent: the scene's state only
            return self.scene.get_sim_state()

    return ScapoViewsEnv


@contextlib.contextmanager
def _render_device(render_backend: str):
    """ManiSkill's render backend for a new environment. "process": the device SAPIEN already renders on in
    this process (SAPIEN renders on one device per process, so the SAPIEN backend's scenes and ManiSkill's
    must share it, and ManiSkill's backend names cannot name a PCI device such as lavapipe's): ManiSkill's
    backend parsing is wrapped, only while the environment is built, to hand it that device."""
    if render_backend != "process":
        yield render_backend
        return
    import sapien
    from mani_skill.envs import sapien_env

    device = sapien.render.RenderSystem().device
    original = sapien_env.parse_sim_and_render_backend

    def parse(sim_backend, _render_backend):
        info = original(sim_backend, "none")
        info.render_device, info.render_backend = device, "sapien_cpu" if device.is_cpu else "sapien_cuda"
        return info

    sapien_env.parse_sim_and_render_backend = parse
    try:
        yield "process"
    finally:
        sapien_env.parse_sim_and_render_backend = original


class ManiSkillRenderer:
    """Renders batches of views of one object in ManiSkill3's parallel sub-scenes (see the module docstring).

    Args:
        camera: our camera config (size, field of view, near, far). num_envs: views per batch (CPU: 1).
        sim_backend, render_backend: ManiSkill's ("auto": GPU when CUDA is available, else CPU).
        shader: SAPIEN shader folder of the camera (``RenderConfig.shader``; "trivial": exact positions and
            segmentation only, as the SAPIEN backend).

    Raises:
        ConfigError: ManiSkill3 is not installed, or more than one view per batch on the CPU simulation.
        RenderError: ManiSkill cannot build the scene (the message names the object).
    """

    def __init__(self, camera: CameraConfig | None = None, num_envs: int = 1, sim_backend: str = "auto",
                 render_backend: str = "auto", shader: str = "trivial"):
        if not available():
            raise ConfigError("the ManiSkill3 backend needs ManiSkill3: pip install 'scapo[maniskill]'")
        import torch

        self.camera_config = camera or CameraConfig()
        gpu = torch.cuda.is_available()
        self.sim_backend = sim_backend if sim_backend != "auto" else ("gpu" if gpu else "cpu")
        self.render_backend = render_backend if render_backend != "auto" else ("gpu" if gpu else "process")
        if self.sim_backend == "cpu" and num_envs > 1:
            raise ConfigError("ManiSkill's CPU simulation holds one sub-scene: num_envs must be 1 without a GPU")
        self.num_envs = int(num_envs)
        self.shader = shader
        self.spec: ArticulationSpec | None = None
        self.env = None

    def load(self, spec: ArticulationSpec) -> None:
        """Build the sub-scenes with ``spec``'s object (a no-op when it is already loaded)."""
        if self.spec is spec:
            return
        self.close()
        import logging

        import sapien

        log = logging.getLogger("mani_skill ")  # (sic: ManiSkill names its logger with a trailing space)
        level = log.level
        log.setLevel(logging.ERROR)  # its "no initial pose" warning: our scene sets the root pose itself
        try:
            sapien.render.set_camera_shader_dir(self.shader)  # the camera below is made with it
            with _render_device(self.render_backend) as backend:
                env_cls = _env_class(self.shader)
                self.env = env_cls(urdf=str(spec.urdf), T_root=spec.T_obj_root, camera=self.camera_config,
                                   num_envs=self.num_envs, obs_mode="none", sim_backend=self.sim_backend,
                                   render_backend=backend)
            self.env.reset(seed=0)
        except Exception as e:  # ManiSkill / SAPIEN raise many kinds for a broken asset or device
            raise RenderError(f"ManiSkill could not build a scene with {spec.urdf}: {e}") from e
        finally:
            log.setLevel(level)
        self._qindex, self._rest = qpos_layout(spec, [j.name for j in self.env.object.get_active_joints()],
                                               "ManiSkill")
        self.lut = segmentation_lut(spec, {ln.name: ln._objs[0].entity.per_scene_id
                                           for ln in self.env.object.get_links()})
        self.K = np.asarray(self.env._sensors["scapo_camera"].camera.get_intrinsic_matrix()[0].cpu().numpy(),
                            dtype=np.float64)
        self._part_links = part_link_names(spec)
        self._inv_rest = invert_transform(np.stack([spec.rest_link_poses[ln] for ln in self._part_links]))
        self.spec = spec

    def render(self, spec: ArticulationSpec, states: np.ndarray, T_world_cams: np.ndarray, rngs) -> list[Frame]:
        """Render ``len(states)`` (at most ``num_envs``) views: ``states (E, J)`` from rest, camera poses
        ``T_world_cams (E, 4, 4)`` (OpenCV); returns one :class:`~scapo.sim.render.Frame` per view."""
        import sapien
        import torch

        self.load(spec)
        E = len(states)
        if not 1 <= E <= self.num_envs:
            raise ConfigError(f"a batch holds 1 to {self.num_envs} views, got {E}")
        qpos = np.tile(self._rest, (self.num_envs, 1))
        qpos[:E, self._qindex] += np.asarray(states, dtype=np.float64)
        env = self.env
        env.object.set_qpos(torch.as_tensor(qpos, dtype=torch.float32, device=env.device))
        if env.gpu_sim_enabled:
            env.scene._gpu_apply_all()
            env.scene.px.gpu_update_articulation_kinematics()
            env.scene._gpu_fetch_all()
        cam = env._sensors["scapo_camera"]
        for i in range(E):
            cam.camera._render_cameras[i].set_local_pose(sapien.Pose(sapien_camera_pose(T_world_cams[i])))
        env.scene.update_render()
        cam.capture()
        obs = cam.get_obs(rgb=False, depth=False, position=True, segmentation=True)
        pos = obs["position"][:E].cpu().numpy()
        seg = obs["segmentation"][:E, ..., 1].cpu().numpy().astype(np.uint32)
        frames = []
        for i in range(E):
            poses = spec.link_poses(states[i])
            motion = np.stack([poses[ln] for ln in self._part_links]) @ self._inv_rest
            frames.append(Frame(spec, np.asarray(states[i], dtype=np.float64), np.asarray(T_world_cams[i]), motion,
                                rngs[i], self.lut, position=pos[i], seg=seg[i]))
        return frames

    def close(self) -> None:
        if self.env is not None:
            self.env.close()
        self.env, self.spec = None, None


def render_many_maniskill(renderer: ManiSkillRenderer, jobs: list[tuple[object, ArticulationSpec, tuple[int, ...]]],
                          cfg: RenderConfig, view: ViewConfig, keep_images: bool = False):
    """:func:`scapo.sim.render.render_many` on the ManiSkill3 backend: the same draws (attempt ``a`` of a job
    uses ``np.random.default_rng((*seed_key, a))``), the same rejections and retries, up to ``num_envs``
    views of one object per batch; yields ``(key, sample, reasons)`` in job order.

    Raises:
        ConfigError: the realistic sensor's support plane (not supported by this backend).
        RenderError: a job exhausted ``cfg.max_attempts`` views (names the object).
    """
    if cfg.sensor.kind == "realistic" and cfg.sensor.ground and view.viewpoints == "upright":
        raise ConfigError("the ManiSkill3 backend renders no support plane: use SensorConfig(ground=False) or the "
                          "SAPIEN backend")
    results: dict[int, tuple[dict, Counter]] = {}
    reasons = {i: Counter() for i in range(len(jobs))}
    pending = [(i, 0) for i in range(len(jobs))]
    while pending:
        spec = jobs[pending[0][0]][1]
        batch = [p for p in pending if jobs[p[0]][1] is spec][: renderer.num_envs]
        pending = [p for p in pending if p not in batch]
        rngs, states, cams = [], [], []
        for i, a in batch:
            rng = np.random.default_rng((*jobs[i][2], a))
            states.append(sample_state(spec, rng))
            cams.append(sample_camera_pose(view, spec.bbox_diag, rng))
            rngs.append(rng)
        frames = renderer.render(spec, np.stack(states), np.stack(cams), rngs)
        retry = []
        for (i, a), frame in zip(batch, frames):
            try:
                sample = process_frame(frame, cfg, renderer.K, keep_images)
            except RejectedViewError as e:
                reasons[i][_reason_key(e.reason)] += 1
                if a + 1 >= cfg.max_attempts:
                    raise RenderError(f"{Path(jobs[i][1].urdf)}: all {cfg.max_attempts} sampled views were rejected "
                                      f"({dict(reasons[i])}); {_rejection_hint(reasons[i], cfg)}") from None
                retry.append((i, a + 1))
                continue
            sample["attempts"] = a + 1
            results[i] = (sample, reasons[i])
        pending = retry + pending
    for i in range(len(jobs)):
        yield jobs[i][0], results[i][0], results[i][1]
