"""SAPIEN rendering of articulated objects into partial point clouds with exact ground truth.

One :class:`Renderer` owns one SAPIEN ``Scene`` and one camera and is reused for every sample of
a worker process; objects are swapped in and out (a new Scene costs seconds on CPU). The object
frame is SAPIEN's world frame: the root link is placed at ``spec.T_obj_root`` so that the
object's canonical frame (SPEC section 3) coincides with the world, and the camera moves.

:func:`render_sample` draws a joint state and a viewpoint, renders ``Position`` and
``Segmentation``, converts positions from SAPIEN's OpenGL camera frame to OpenCV once
(:data:`scapo.ops.rigid.R_CV_GL`), labels points by part, resamples them by farthest-point
sampling and assembles the ground truth with the field names of SPEC section 5.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scapo.errors import AssetError, ConfigError, RejectedViewError, RenderError
from scapo.ops.rigid import invert_transform, look_at, normalize, sapien_camera_pose, transform_points
from scapo.ops.sampling import farthest_point_indices
from scapo.sim.assets.templates import ViewTemplate
from scapo.sim.assets.urdf import ArticulationSpec
from scapo.sim.sensor import SensorConfig, apply_sensor

#: Joint-state rules of :attr:`RenderConfig.state`.
STATES = ("sampled", "rest")

_VULKAN_HELP = (
    "SAPIEN found no Vulkan rendering device. On CPU-only machines it needs Mesa >= 24.3 (lavapipe); "
    "on Debian bookworm run 'bash scripts/setup.sh' (adds bookworm-backports and installs "
    "mesa-vulkan-drivers libvulkan1 from it), elsewhere install Mesa >= 24.3 or a GPU Vulkan driver. "
    "'scapo doctor' shows what is found."
)


#: The largest image side the renderer is asked for (Vulkan's common image limit is 16384; a 4096 x 4096 depth image
#: already holds 16 M points, 16000 x more than a cloud keeps).
MAX_IMAGE_SIDE = 4096


@dataclass(frozen=True)
class CameraConfig:
    """Pinhole camera of the renderer."""

    width: int = 256
    """Image width (pixels)."""
    height: int = 256
    """Image height (pixels)."""
    fovy_deg: float = 45.0
    """Vertical field of view (degrees)."""
    near: float = 0.01
    """Near clipping plane (m)."""
    far: float = 20.0
    """Far clipping plane (m)."""

    def __post_init__(self):
        if self.width < 1 or self.height < 1:
            raise ConfigError(f"image size must be at least 1 x 1 pixels, got {self.width} x {self.height}")
        if self.width > MAX_IMAGE_SIDE or self.height > MAX_IMAGE_SIDE:
            raise ConfigError(f"image size {self.width} x {self.height} is beyond what the renderer allocates (at most "
                              f"{MAX_IMAGE_SIDE} pixels a side); the default 256 x 256 gives 1024-point clouds")
        if not 0.0 < self.fovy_deg < 180.0:
            raise ConfigError(f"fovy_deg must be in (0, 180), got {self.fovy_deg}")
        if not 0.0 < self.near < self.far:
            raise ConfigError(f"need 0 < near < far, got near={self.near}, far={self.far}")


#: The viewpoint settings of ``scapo generate --viewpoints`` (:attr:`ViewConfig.viewpoints`).
VIEWPOINTS = ("upright", "paper", "sphere")


@dataclass(frozen=True)
class ViewConfig:
    """Viewpoint distribution around the object (degrees; distance in units of the rest bbox diagonal).

    Three settings (:attr:`viewpoints`, ``scapo generate --viewpoints``), which :func:`sample_camera_pose` draws
    from:

    - ``upright`` (default): azimuth 0 puts the camera in front of the object (on its -x side); positive
      azimuth moves it towards -y; elevation is the angle above the object's xy plane; a small roll.
    - ``sphere``: the relative rotation is drawn uniformly from SO(3) (camera direction uniform on the sphere,
      uniform roll); the angle ranges are ignored.
    - ``paper``: EAP's synthetic views (Liu et al., NeurIPS 2022; code ``Meowuu7/equi-articulated-pose``,
      ``SPConvNets/datasets/MotionHOIDatasetPartial.py`` around lines 288-299 and ``MotionDatasetPartial.py``
      around lines 371-384), which OP-Align and SCAPO follow: the camera sits in the object's level front view (on
      its -x side, at elevation 0, no roll, at ``distance``) and the object is turned about its rest bounding-box
      centre (the object frame's origin) by ``R = Rz @ Ry @ Rx`` with each Euler angle (x, y, z; degrees) drawn
      uniformly in its range of :attr:`object_euler_deg`. The angle ranges and roll are ignored.

    Raises:
        ConfigError: an unknown setting, ``paper`` without its Euler ranges or ranges without ``paper``, or
            malformed ranges.
    """

    azimuth_deg: tuple[float, float] = (-70.0, 70.0)
    elevation_deg: tuple[float, float] = (10.0, 60.0)
    distance: tuple[float, float] = (1.4, 2.4)
    roll_deg: tuple[float, float] = (-5.0, 5.0)
    viewpoints: str = "upright"
    """"upright", "sphere" or "paper" (:data:`VIEWPOINTS`; see the class docstring)."""
    target_jitter: float = 0.03
    """Std of the look-at point around the bbox centre, in bbox diagonals (``paper``: of the camera's position,
    its orientation kept, so that the object's rotation away from the front view is exactly the Euler one)."""
    object_euler_deg: tuple[tuple[float, float], tuple[float, float], tuple[float, float]] | None = None
    """``paper`` viewpoints: the ranges of the object's Euler angles about x, y and z (degrees), ``R = Rz Ry Rx``;
    None for the other settings."""

    def __post_init__(self):
        if self.viewpoints not in VIEWPOINTS:
            raise ConfigError(f"unknown viewpoints {self.viewpoints!r}; known: {', '.join(VIEWPOINTS)}")
        if (self.viewpoints == "paper") != (self.object_euler_deg is not None):
            raise ConfigError("the paper's viewpoints need the object's Euler ranges (object_euler_deg), and the "
                              f"ranges are theirs alone; got viewpoints {self.viewpoints!r} with object_euler_deg "
                              f"{self.object_euler_deg!r}: give --viewpoints paper (with --euler), or no ranges")
        if self.object_euler_deg is not None:
            eul = self.object_euler_deg
            ok = isinstance(eul, (tuple, list)) and len(eul) == 3 and all(
                isinstance(r, (tuple, list)) and len(r) == 2
                and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in r)
                and -180.0 <= r[0] <= r[1] <= 180.0 for r in eul)
            if not ok:
                raise ConfigError(f"object_euler_deg must be three [low, high] ranges of degrees (x, y, z) within "
                                  f"[-180, 180] with low <= high, got {eul!r}")
            object.__setattr__(self, "object_euler_deg", tuple((float(r[0]), float(r[1])) for r in eul))

    @classmethod
    def from_template(cls, view: ViewTemplate) -> ViewConfig:
        """The ``upright`` setting with a category template's angle and distance ranges."""
        return cls(view.azimuth_deg, view.elevation_deg, view.distance, view.roll_deg)

    def with_fields(self, fields: dict) -> ViewConfig:
        """This view with ``fields`` (ViewConfig field names, e.g. a per-object view of ``--object-options``, or a
        stored config's view) replaced. Two older spellings are read as the setting they meant: ``random_rotation``
        (true: ``viewpoints="sphere"``; false: nothing) and ``object_euler_deg`` alone (``viewpoints="paper"``).

        Raises:
            ConfigError: an unknown field, or a contradiction (see the class)."""
        fields = dict(fields)
        if "random_rotation" in fields:
            if fields.pop("random_rotation"):
                fields.setdefault("viewpoints", "sphere")
        if fields.get("object_euler_deg") is not None:
            fields.setdefault("viewpoints", "paper")
        if fields.get("viewpoints", self.viewpoints) != "paper":
            fields.setdefault("object_euler_deg", None)
        try:
            return dataclasses.replace(self, **fields)
        except TypeError as e:
            raise ConfigError(f"not a view ({e}); known fields: "
                              f"{', '.join(f.name for f in dataclasses.fields(self))}") from None

    def stored(self) -> dict:
        """The JSON form of a dataset's config (``GenerateConfig.to_dict``): the setting is written as datasets made
        before :attr:`viewpoints` was a field wrote it (``random_rotation``; the Euler ranges only for ``paper``),
        so that their config hashes hold and they resume; :meth:`with_fields` reads it back."""
        d = dataclasses.asdict(self)
        d["random_rotation"] = d.pop("viewpoints") == "sphere"
        if d["object_euler_deg"] is None:
            del d["object_euler_deg"]
        else:
            d["object_euler_deg"] = [list(r) for r in d["object_euler_deg"]]
        return d


CROPPED = ("keep", "reject", "flag")
SYMMETRIC_LABELS = ("asset", "view")


@dataclass(frozen=True)
class RenderConfig:
    """How one sample is rendered and resampled."""

    camera: CameraConfig = field(default_factory=CameraConfig)
    num_points: int = 1024
    """Points per sample after farthest-point sampling (N)."""
    min_part_fraction: float = 0.05
    """A view is rejected when any part keeps fewer than ceil(fraction * N) of the N points."""
    max_attempts: int = 50
    """Views tried per sample before giving up with an error."""
    shader: str = "trivial"
    """SAPIEN camera shader folder; "trivial" outputs exact float positions and segmentation only."""
    fps_candidates: int = 8192
    """FPS input bound: when at least 4x this many object pixels are visible, FPS runs on a regular
    pixel sub-grid (every s-th row and column, s = floor(sqrt(pixels / fps_candidates))) that keeps
    at least this many; 0 uses every pixel. Keep it well above num_points: with fewer than ~8x N
    candidates FPS becomes biased towards sparsely sampled (oblique) surfaces."""
    sensor: SensorConfig = field(default_factory=SensorConfig)
    cropped: str = "keep"
    """Views whose object touches the image border: "keep" them (the default of datasets made before this
    rule existed, e.g. Table 1's), "reject" them (counted like other rejections) or "flag" them (kept, with a
    per-sample ``cropped`` flag in the shards and the manifest)."""
    complete: bool = False
    """Sample the points on the whole posed mesh (every surface, seen from the camera or not; area-weighted, then
    farthest-point sampled to N) instead of rendering a depth view: EAP's complete-shape setting and the first rungs
    of ``scapo bench ladder``. The camera pose is still drawn (it fixes the frame the points are given in); the
    image, the sensor, the border rule and visibility play no part."""
    state: str = "sampled"
    """Joint states: "sampled" uniformly within the limits, or "rest" (every sample at the rest state: the
    one-state rung of ``scapo bench ladder``)."""
    parts_alone: bool = False
    """Render every part in a scene of its own (the other parts hidden, the same camera and joint state) and pool
    their points before the resampling, so that no part hides another, only itself: the data regime of EAP's
    synthetic partial clouds that OP-Align and SCAPO inherit (``SPConvNets/datasets/MotionDatasetPartial.py``,
    ``create_partial_pts``, in ``Meowuu7/equi-articulated-pose`` and its copy in ``YC-Che/OP-Align``: a pyrender
    scene of each part's triangles alone, its depth back-projected, the parts' points concatenated);
    ``scapo generate --parts-alone``. Clean sensor only."""
    symmetric_labels: str = "asset"
    """Categories with a symmetry that exchanges parts (:mod:`scapo.sim.assets.symmetry`, e.g. basket): keep the
    "asset"'s part labels (the default of datasets made before this rule existed), or label "view" by view (of the
    two valid ground truths, the one whose front faces the camera). No effect on other categories."""

    def __post_init__(self):
        if self.cropped not in CROPPED:
            raise ConfigError(f"cropped must be one of {CROPPED}, got {self.cropped!r}")
        if self.symmetric_labels not in SYMMETRIC_LABELS:
            raise ConfigError(f"symmetric_labels must be one of {SYMMETRIC_LABELS}, got {self.symmetric_labels!r}")
        if self.num_points < 16:
            raise ConfigError(f"the number of points per sample (--points) must be >= 16, got {self.num_points}")
        if not 0.0 <= self.min_part_fraction < 1.0:
            raise ConfigError(f"min_part_fraction must be in [0, 1), got {self.min_part_fraction}")
        pixels = self.camera.width * self.camera.height
        if pixels < self.num_points:
            c = self.camera
            raise ConfigError(f"an image of {c.width} x {c.height} pixels has fewer pixels ({pixels}) than the "
                              f"{self.num_points} points per sample; raise --width/--height or lower --points")
        if self.max_attempts < 1:
            raise ConfigError(f"max_attempts must be >= 1, got {self.max_attempts}")
        if self.state not in STATES:
            raise ConfigError(f"unknown joint-state rule {self.state!r} (--state); known: {', '.join(STATES)}")
        if self.complete and self.sensor.kind != "clean":
            raise ConfigError("--complete samples the mesh surface: it has no sensor model; leave --sensor clean")
        if self.parts_alone and (self.complete or self.sensor.kind != "clean"):
            raise ConfigError("--parts-alone renders every part's depth view alone (EAP's data regime): it takes the "
                              "clean sensor and rendered views; leave out --complete and --sensor")

    @property
    def min_part_points(self) -> int:
        return int(math.ceil(self.min_part_fraction * self.num_points))


@dataclass
class Frame:
    """One captured view, not yet turned into a sample.

    Attributes:
        spec: the object. state: (J,) joint state. T_world_cam: (4,4) camera pose (OpenCV).
        part_motion: (P,4,4) rest -> current motion of each part (object frame), from SAPIEN.
        position: (H,W,4) float32 SAPIEN ``Position`` picture (OpenGL camera frame); with ``parts_alone``
            ``(P,H,W,4)``, one picture per part rendered alone.
        seg: (H,W) uint32 entity ids (0 = nothing hit), ``(P,H,W)`` with ``parts_alone``. lut: entity id -> part
            (-1 = not a part).
        rng: the generator of this attempt (continues into FPS and sensor noise).
        ground: whether a support plane was in the picture.
    """

    spec: ArticulationSpec
    state: np.ndarray
    T_world_cam: np.ndarray
    part_motion: np.ndarray
    rng: np.random.Generator
    lut: np.ndarray
    position: np.ndarray | None = None
    seg: np.ndarray | None = None
    ground: bool = False


class Renderer:
    """A SAPIEN scene with one camera, reused for many objects and views.

    Rendering is split into :meth:`submit` (pose the object and camera, start the picture;
    SAPIEN returns before the rasteriser finishes) and :meth:`fetch` (wait and copy the
    pictures), so that CPU work on the previous frame can overlap with rendering.

    Args:
        camera: image size and intrinsics. shader: SAPIEN shader folder ("trivial" is exact and
            fastest; "default" also computes lighting).

    Raises:
        RenderError: if SAPIEN finds no Vulkan device (the message says what to install).
    """

    def __init__(self, camera: CameraConfig | None = None, shader: str = "trivial"):
        import sapien

        self._sapien = sapien
        self.camera_config = camera or CameraConfig()
        try:
            sapien.render.set_camera_shader_dir(shader)
            self.scene = sapien.Scene()
            c = self.camera_config
            self.camera = self.scene.add_camera("scapo_camera", c.width, c.height, math.radians(c.fovy_deg),
                                                c.near, c.far)
        except RuntimeError as e:
            if "device" in str(e).lower():
                raise RenderError(f"{e}. {_VULKAN_HELP}") from e
            raise RenderError(f"SAPIEN failed to set up the scene: {e}") from e
        self.K = np.asarray(self.camera.get_intrinsic_matrix(), dtype=np.float64)
        self.spec: ArticulationSpec | None = None
        self._art = None
        self._ground = None
        self._pending: Frame | None = None
        self._bodies: list[tuple[int, list]] = []  # (part or -1, render bodies) of each link of the loaded object
        self.lut = np.full(1, -1, dtype=np.int64)

    # ------------------------------------------------------------------ objects
    def load(self, spec: ArticulationSpec) -> None:
        """Put ``spec``'s object in the scene (removing the previous one); no-op if already loaded.

        Raises:
            AssetError: if SAPIEN cannot load the URDF or its joints differ from the spec.
        """
        if self.spec is spec:
            return
        self.unload()
        loader = self.scene.create_urdf_loader()
        loader.fix_root_link = True
        try:
            art = loader.load(str(spec.urdf))
        except Exception as e:  # SAPIEN raises RuntimeError / filesystem errors with terse text
            raise AssetError(f"SAPIEN could not load {spec.urdf}: {e}") from e
        if art is None:
            raise AssetError(f"SAPIEN could not load {spec.urdf} (no articulation returned)")
        art.set_root_pose(self._sapien.Pose(spec.T_obj_root))
        self._qindex, self._rest_qpos = qpos_layout(spec, [j.name for j in art.get_active_joints()], "SAPIEN",
                                                    AssetError)
        links = {ln.name: ln for ln in art.get_links()}
        self._part_links = [links[name] for name in part_link_names(spec)]
        self._inv_rest = invert_transform(np.stack([spec.rest_link_poses[ln.name] for ln in self._part_links]))
        self.lut = segmentation_lut(spec, {ln.name: ln.entity.per_scene_id for ln in art.get_links()})
        self._bodies = [(int(self.lut[ln.entity.per_scene_id]) if ln.entity.per_scene_id < len(self.lut) else -1,
                         [c for c in ln.entity.components
                          if isinstance(c, self._sapien.render.RenderBodyComponent)]) for ln in art.get_links()]
        self._art, self.spec = art, spec

    def unload(self) -> None:
        """Remove the current object from the scene."""
        if self._art is not None:
            self.scene.remove_articulation(self._art)
        self._art, self.spec = None, None

    def set_state(self, state: np.ndarray) -> None:
        """Set joint ``state (J,)`` (rad / m, from rest) of the loaded object."""
        qpos = self._rest_qpos.copy()
        qpos[self._qindex] += np.asarray(state, dtype=np.float64)
        self._art.set_qpos(qpos.astype(np.float32))

    def part_motion(self) -> np.ndarray:
        """(P, 4, 4) float64 motion of each part from rest to the current state, in the object frame.

        Read from SAPIEN's link poses (what is rendered): ``pose_now @ inv(pose_rest)`` of each
        part's first link.
        """
        now = np.stack([ln.entity_pose.to_transformation_matrix() for ln in self._part_links]).astype(np.float64)
        return now @ self._inv_rest

    def set_ground(self, altitude: float | None) -> None:
        """Show a support plane at ``altitude`` (m, object frame z) or hide it (None)."""
        if altitude is None:
            if self._ground is not None:
                self._ground.set_pose(self._sapien.Pose([0, 0, -1e4]))
            return
        if self._ground is None:
            b = self.scene.create_actor_builder()
            b.add_box_visual(half_size=[20.0, 20.0, 0.005])
            self._ground = b.build_kinematic(name="scapo_ground")
        self._ground.set_pose(self._sapien.Pose([0.0, 0.0, altitude - 0.005]))

    # ------------------------------------------------------------------ pictures
    def submit(self, spec: ArticulationSpec, state: np.ndarray, T_world_cam: np.ndarray, rng: np.random.Generator,
               ground: bool = False, parts_alone: bool = False) -> Frame:
        """Pose ``spec`` at ``state``, place the camera at ``T_world_cam`` (4x4, OpenCV convention)
        and start rendering. Only one frame can be pending; :meth:`fetch` completes it. ``parts_alone``
        (:attr:`RenderConfig.parts_alone`): one picture per part with the other parts hidden, taken here."""
        if self._pending is not None:
            raise RenderError("submit() called while a frame is pending; fetch() it first")
        self.load(spec)
        state = np.asarray(state, dtype=np.float64)
        self.set_state(state)
        motion = self.part_motion()
        self.set_ground(_support_altitude(spec, motion) if ground else None)
        self.camera.set_entity_pose(self._sapien.Pose(sapien_camera_pose(T_world_cam)))
        T_world_cam = np.asarray(T_world_cam, dtype=np.float64)
        self._pending = Frame(spec, state, T_world_cam, motion, rng, self.lut, ground=ground)
        if parts_alone:
            self._pending.position, self._pending.seg = self._parts_alone_pictures(spec.num_parts)
            return self._pending
        self.scene.update_render()
        self.camera.take_picture()
        return self._pending

    def _parts_alone_pictures(self, num_parts: int) -> tuple[np.ndarray, np.ndarray]:
        """``(P,H,W,4)`` positions and ``(P,H,W)`` entity ids, part ``p``'s picture with every other link hidden
        (its render bodies disabled, enabled again after)."""
        pos, seg = [], []
        try:
            for p in range(num_parts):
                for part, bodies in self._bodies:
                    for b in bodies:
                        b.enable() if part == p else b.disable()
                self.scene.update_render()
                self.camera.take_picture()
                pos.append(np.array(self.camera.get_picture("Position")))
                seg.append(np.array(self.camera.get_picture("Segmentation")[..., 1]))
        finally:
            for _, bodies in self._bodies:
                for b in bodies:
                    b.enable()
        return np.stack(pos), np.stack(seg)

    def fetch(self) -> Frame:
        """Wait for the pending frame and copy its ``Position`` and ``Segmentation`` pictures."""
        frame, self._pending = self._pending, None
        if frame is None:
            raise RenderError("fetch() without a submitted frame")
        if frame.position is not None:  # parts alone: taken by submit
            return frame
        frame.position = self.camera.get_picture("Position")
        frame.seg = self.camera.get_picture("Segmentation")[..., 1]  # uint32 entity ids (view, no copy)
        return frame

    def capture(self, T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Render the loaded object (at its current state) from ``T_world_cam``.

        Returns:
            points_cam: (H, W, 3) float32 positions in the OpenCV camera frame (m);
            part_map: (H, W) int64 part index per pixel, -1 where no object part is hit;
            valid: (H, W) bool, pixels that hit any surface.
        """
        self.camera.set_entity_pose(self._sapien.Pose(sapien_camera_pose(T_world_cam)))
        self.scene.update_render()
        self.camera.take_picture()
        pos = self.camera.get_picture("Position")
        seg = self.camera.get_picture("Segmentation")[..., 1].astype(np.int64)
        return gl_to_cv(pos), _part_map(seg, self.lut), seg > 0

    def close(self) -> None:
        self.unload()
        self.scene = None


def qpos_layout(spec: ArticulationSpec, active: list[str], engine: str, error=RenderError
                ) -> tuple[np.ndarray, np.ndarray]:
    """Where each GT joint sits in a simulator's qpos vector (``active``: its movable joint names, in its
    order) and the rest-state qpos: ``(qindex (J,) int64, rest (len(active),) float64)``.

    Raises:
        ``error``: the simulator's movable joints are not the URDF's (names both)."""
    try:
        qindex = np.array([active.index(j.name) for j in spec.gt_joints], dtype=np.int64)
    except ValueError:
        raise error(f"{spec.urdf}: {engine}'s movable joints {active} differ from the URDF's "
                    f"{[j.name for j in spec.gt_joints]}") from None
    rest = np.zeros(len(active))
    for j, qi in zip(spec.gt_joints, qindex):
        rest[qi] = j.rest_qpos
    return qindex, rest


def part_link_names(spec: ArticulationSpec) -> list[str]:
    """The link whose pose stands for each part (its first link), part order."""
    return [next(n for n, idx in spec.part_of_link.items() if idx == p) for p in range(spec.num_parts)]


def segmentation_lut(spec: ArticulationSpec, ids: dict[str, int]) -> np.ndarray:
    """Part index per segmentation id, from link name -> the simulator's per-scene entity id (-1: no part)."""
    lut = np.full(max(ids.values()) + 1, -1, dtype=np.int64)
    for name, sid in ids.items():
        lut[sid] = spec.part_of_link.get(name, -1)
    return lut


def gl_to_cv(position: np.ndarray) -> np.ndarray:
    """SAPIEN ``Position`` picture (..., 4) in the OpenGL camera frame -> (..., 3) float32 OpenCV frame."""
    return position[..., :3] * np.array([1.0, -1.0, -1.0], dtype=np.float32)


def _part_map(seg: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """Part index per pixel from entity ids (ids outside the table map to -1)."""
    return np.where(seg < len(lut), lut[np.minimum(seg, len(lut) - 1)], -1)


# ---------------------------------------------------------------------- sampling
def sample_state(spec: ArticulationSpec, rng: np.random.Generator, ranges: np.ndarray | None = None) -> np.ndarray:
    """Joint states (J,) float64 drawn uniformly in ``ranges (J, 2)`` (default: the joint limits)."""
    r = spec.joint_limit if ranges is None else np.asarray(ranges, dtype=np.float64)
    return r[:, 0] + rng.random(len(r)) * (r[:, 1] - r[:, 0])


def sample_camera_pose(view: ViewConfig, bbox_diag: float, rng: np.random.Generator) -> np.ndarray:
    """Camera pose ``T_world_cam (4, 4)`` (OpenCV convention, object frame = world) looking at the object's bbox
    centre, drawn from ``view`` (:class:`ViewConfig`'s three settings) with ``rng``.

    ``paper``: the camera's level front pose ``T_front`` (on -x at the drawn distance, looking along +x, z up,
    moved by the jitter without turning) and the object turned by ``R`` about the origin give
    ``T_world_cam = [R^T | 0] @ T_front``, so that ``T_cam_obj = inv(T_front) @ [R | 0]``: the object's rotation
    away from its level front view is ``R`` exactly.
    """
    if view.viewpoints == "paper":
        R = object_rotation(view.object_euler_deg, rng)
        dist = rng.uniform(*view.distance) * bbox_diag
        eye = np.array([-dist, 0.0, 0.0]) + rng.normal(scale=view.target_jitter * bbox_diag, size=3)
        T_front = look_at(eye, eye + np.array([dist, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]))
        turn = np.eye(4)
        turn[:3, :3] = R.T
        return turn @ T_front
    if view.viewpoints == "sphere":
        d = normalize(rng.normal(size=3))
        roll = rng.uniform(0.0, 2 * np.pi)
    else:
        az = math.radians(rng.uniform(*view.azimuth_deg))
        el = math.radians(rng.uniform(*view.elevation_deg))
        d = np.array([-math.cos(el) * math.cos(az), -math.cos(el) * math.sin(az), math.sin(el)])
        roll = math.radians(rng.uniform(*view.roll_deg))
    dist = rng.uniform(*view.distance) * bbox_diag
    target = rng.normal(scale=view.target_jitter * bbox_diag, size=3)
    up = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.999 else np.array([1.0, 0.0, 0.0])
    T = look_at(target + dist * d, target, up)
    c, s = math.cos(roll), math.sin(roll)
    T[:3, :3] = T[:3, :3] @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return T


def object_rotation(euler_deg, rng: np.random.Generator) -> np.ndarray:
    """The object's turn of the ``paper`` viewpoints: ``(3, 3)`` float64 ``R = Rz @ Ry @ Rx`` with the angles about
    x, y and z (in this order from ``rng``) uniform in ``euler_deg``'s three ``(low, high)`` ranges (degrees), as
    EAP's ``MotionDatasetPartial.py`` (around lines 371-384) composes them."""
    ax, ay, az = (math.radians(rng.uniform(lo, hi)) for lo, hi in euler_deg)
    cx, sx, cy, sy, cz, sz = math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay), math.cos(az), math.sin(az)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    Ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    Rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ Ry @ Rx


def front_view_angle_deg(T_cam_obj: np.ndarray) -> float:
    """The object's rotation away from its level front view (degrees), from a sample's ``T_cam_obj (4, 4)``: the
    angle of ``R_front @ R_cam_obj``, where ``R_front`` (the level front camera's rotation in the object frame,
    looking along +x with z up) is what ``R_cam_obj`` is for an unturned object. 0 for the ``paper`` setting's
    front view; its ``R``'s angle otherwise."""
    R_front = look_at(np.array([-1.0, 0.0, 0.0]), np.zeros(3), np.array([0.0, 0.0, 1.0]))[:3, :3]
    R = R_front @ np.asarray(T_cam_obj, dtype=np.float64)[:3, :3]
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0))))


def _support_altitude(spec: ArticulationSpec, part_pose_obj: np.ndarray) -> float:
    """Lowest z (object frame) of the object at the given part poses (uses part-mesh hull vertices)."""
    zmin = np.inf
    for p in range(spec.num_parts):
        v = _hull_vertices(spec, p)
        zmin = min(zmin, float(transform_points(part_pose_obj[p], v)[:, 2].min()))
    return zmin


_HULLS: dict[tuple[str, int], np.ndarray] = {}


def _hull_vertices(spec: ArticulationSpec, part: int) -> np.ndarray:
    key = (str(spec.urdf), part)
    if key not in _HULLS:
        _HULLS[key] = np.asarray(_rest_mesh(spec, part).convex_hull.vertices)
    return _HULLS[key]


def process_frame(frame: Frame, cfg: RenderConfig, K: np.ndarray, keep_images: bool = False) -> dict:
    """Turn a captured frame into a sample dict with the SPEC section 5 fields.

    Object pixels are back-projected (exact positions from the ``Position`` picture, converted
    once from OpenGL to OpenCV), labelled by part, and resampled to N points by farthest-point
    sampling. When at least 4x ``cfg.fps_candidates`` object pixels are visible, FPS runs on a
    regular image-space sub-grid (every s-th row and column) holding at least that many.

    Returned arrays: ``points (N,3) f32`` camera frame m; ``part_label (N,) int64`` (-1 not
    object); ``npcs (N,3) f32`` rest object-frame coordinates / bbox_diag (0 for non-object
    points); ``part_pose (P,4,4) f64`` object-at-rest -> camera-at-state; ``joint_type (J,)
    int64``; ``joint_parts (J,2) int64``; ``joint_axis (J,3) f64`` and ``joint_pivot (J,3) f64``
    camera frame; ``joint_state (J,) f64``; ``joint_limit (J,2) f64``; ``T_cam_obj (4,4) f64``;
    ``K (3,3) f64``; ``bbox_diag () f64``. With ``keep_images`` also ``image_part_map (H,W)``
    (-2 nothing hit, -1 not object, else part index) for previews.

    Raises:
        RejectedViewError: the camera sees fewer than N object pixels, or some part keeps fewer
            than ``cfg.min_part_points`` of the N points; the reason says which.
        RenderError: the picture contains NaN/inf positions.
    """
    spec, rng, N = frame.spec, frame.rng, cfg.num_points
    seg, lut = frame.seg, frame.lut
    if cfg.sensor.kind == "clean":
        obj_mask = seg > 0  # no support plane with the clean sensor: every hit is the object
        n_obj = int(np.count_nonzero(obj_mask))
        if n_obj < N:
            raise RejectedViewError(f"too few object pixels ({n_obj} < {N})")
        stride = max(1, int(math.sqrt(n_obj / cfg.fps_candidates))) if cfg.fps_candidates else 1
        sub_mask = obj_mask[..., ::stride, ::stride]  # (H, W), or (P, H, W): the parts alone, pooled
        points_all = gl_to_cv(frame.position[..., ::stride, ::stride, :][sub_mask])
        labels_all = _part_map(seg[..., ::stride, ::stride][sub_mask], lut)
    else:
        part_map = _part_map(seg, lut)
        obj_mask = part_map >= 0
        img_points, keep, label = apply_sensor(gl_to_cv(frame.position), seg > 0, part_map, cfg.sensor, rng)
        n_obj = int(np.count_nonzero((label >= 0) & keep))
        if n_obj < N:
            raise RejectedViewError(f"too few object pixels ({n_obj} < {N})")
        points_all, labels_all = img_points[keep], label[keep]
    cropped = bool(obj_mask[..., 0, :].any() or obj_mask[..., -1, :].any() or obj_mask[..., :, 0].any()
                   or obj_mask[..., :, -1].any())
    if cropped and cfg.cropped == "reject":
        raise RejectedViewError("object cropped by the image border")
    if not np.isfinite(points_all).all():
        raise RenderError("SAPIEN returned non-finite positions")
    idx = farthest_point_indices(points_all, N, rng)
    points = points_all[idx]
    part_label = labels_all[idx]
    counts = np.bincount(part_label[part_label >= 0], minlength=spec.num_parts)
    if counts.min() < cfg.min_part_points:
        p = int(counts.argmin())
        raise RejectedViewError(f"part {p} {spec.part_names[p]!r} keeps {int(counts[p])} < {cfg.min_part_points} "
                                "points")
    sample = ground_truth(spec, frame.state, frame.T_world_cam, frame.part_motion, points, part_label, K)
    if cfg.cropped == "flag":
        sample["cropped"] = cropped
    if keep_images:
        if seg.ndim == 3:  # parts alone: each pixel shows the nearest of the parts' pictures
            depth = np.where(seg > 0, -frame.position[..., 2], np.inf)
            near = depth.argmin(0)
            seg = np.take_along_axis(seg, near[None], 0)[0]
        img = np.full(seg.shape, -2, dtype=np.int64)
        img[seg > 0] = -1
        pm = _part_map(seg, lut)
        img[pm >= 0] = pm[pm >= 0]
        sample["image_part_map"] = img
    return sample


def npcs_of(points: np.ndarray, part_label: np.ndarray, part_pose: np.ndarray, bbox_diag: float) -> np.ndarray:
    """The NPCS of one view's points (SPEC section 5): ``inv(part_pose[label]) @ point / bbox_diag``.

    Args:
        points: ``(N, 3)`` float32, camera frame, metres.
        part_label: ``(N,)`` int; ``-1`` (background) gets NPCS ``0``.
        part_pose: ``(P, 4, 4)`` float64, each part's pose (object at rest -> camera at state).
        bbox_diag: the object's rest bounding-box diagonal, metres.

    Returns:
        ``(N, 3)`` float32, in units of ``bbox_diag``: computed in float64 and rounded once to float32, so that the
        generator and :func:`scapo.bench.archive.reconcile_dataset` (which computes it again from archived ground
        truth) give the same bits from the same inputs.
    """
    points = np.asarray(points, dtype=np.float32)
    part_label = np.asarray(part_label)
    npcs = np.zeros_like(points)
    obj = part_label >= 0
    inv_pose = invert_transform(np.asarray(part_pose, dtype=np.float64))[part_label[obj]]
    npcs[obj] = (np.einsum("nij,nj->ni", inv_pose[:, :3, :3], points[obj]) + inv_pose[:, :3, 3]) / bbox_diag
    return npcs


def ground_truth(spec: ArticulationSpec, state: np.ndarray, T_world_cam: np.ndarray, part_motion: np.ndarray,
                 points: np.ndarray, part_label: np.ndarray, K: np.ndarray) -> dict:
    """Assemble the SPEC section 5 sample dict from the simulator state of one frame.

    ``part_pose[p] = T_cam_world @ part_motion[p]`` (object at rest -> camera at state; the
    object frame is the world frame); joint axes and pivots are the rest-state values of the
    spec moved by the parent part's pose; ``npcs = inv(part_pose[label]) @ points / bbox_diag``.
    """
    T_cam_world = invert_transform(T_world_cam)
    part_pose = T_cam_world @ part_motion
    points = np.asarray(points, dtype=np.float32)
    npcs = npcs_of(points, part_label, part_pose, spec.bbox_diag)
    jp = spec.joint_parts
    axes = np.array([j.axis_obj for j in spec.gt_joints]).reshape(-1, 3)
    pivots = np.array([j.pivot_obj for j in spec.gt_joints]).reshape(-1, 3)
    parent = part_pose[jp[:, 0]] if len(jp) else np.zeros((0, 4, 4))
    return {
        "points": points,
        "part_label": part_label.astype(np.int64),
        "npcs": npcs,
        "part_pose": part_pose,
        "joint_type": spec.joint_type,
        "joint_parts": jp,
        "joint_axis": np.einsum("jik,jk->ji", parent[:, :3, :3], axes),
        "joint_pivot": np.einsum("jik,jk->ji", parent[:, :3, :3], pivots) + parent[:, :3, 3],
        "joint_state": np.asarray(state, dtype=np.float64).copy(),
        "joint_limit": spec.joint_limit,
        "T_cam_obj": T_cam_world,
        "K": np.asarray(K, dtype=np.float64).copy(),
        "bbox_diag": np.float64(spec.bbox_diag),
    }


def _draw_state(spec: ArticulationSpec, cfg: RenderConfig, rng: np.random.Generator) -> np.ndarray:
    """A sample's joint state under ``cfg.state`` (the draw is made either way, so that a "rest" dataset's views are
    those of the "sampled" one)."""
    state = sample_state(spec, rng)
    return np.zeros_like(state) if cfg.state == "rest" else state


_REST_MESHES: dict[tuple[str, int], object] = {}


def _rest_mesh(spec: ArticulationSpec, part: int):
    key = (str(spec.urdf), part)
    if key not in _REST_MESHES:
        from scapo.sim.assets.urdf import load_part_mesh

        if len(_REST_MESHES) > 256:
            _REST_MESHES.clear()
        _REST_MESHES[key] = load_part_mesh(spec, part)
    return _REST_MESHES[key]


def sample_complete(renderer: Renderer, spec: ArticulationSpec, cfg: RenderConfig, view: ViewConfig,
                    rng: np.random.Generator) -> dict:
    """One sample of the ``complete`` setting (:attr:`RenderConfig.complete`): the joint state and camera pose are
    drawn as for a rendered view, the parts are posed by SAPIEN (``Renderer.part_motion``, as rendered samples are),
    ``8 N`` points are drawn on the union of the posed part meshes with probability proportional to area
    (``trimesh.sample.sample_surface``), and farthest-point sampling keeps ``N``.

    Returns the sample dict of :func:`process_frame` (camera-frame points in metres, exact part labels, NPCS and
    ground truth). Raises RejectedViewError when a part keeps fewer than ``cfg.min_part_points`` points (a part of
    tiny area) and AssetError when a part has no surface.
    """
    import trimesh

    state = _draw_state(spec, cfg, rng)
    T_world_cam = sample_camera_pose(view, spec.bbox_diag, rng)
    renderer.load(spec)
    renderer.set_state(state)
    motion = renderer.part_motion()
    T_cam_world = invert_transform(np.asarray(T_world_cam, dtype=np.float64))
    meshes, labels = [], []
    for p in range(spec.num_parts):
        m = _rest_mesh(spec, p).copy()
        if m.area <= 0:
            raise AssetError(f"{spec.urdf}: part {p} {spec.part_names[p]!r} has no surface to sample")
        m.apply_transform(T_cam_world @ motion[p])
        meshes.append(m)
        labels.append(np.full(len(m.faces), p, dtype=np.int64))
    whole = trimesh.util.concatenate(meshes)
    face_part = np.concatenate(labels)
    N = cfg.num_points
    pts, face = trimesh.sample.sample_surface(whole, 8 * N, seed=int(rng.integers(2**31)))
    pts = np.asarray(pts, dtype=np.float64)
    idx = farthest_point_indices(pts, N, rng)
    points, part_label = pts[idx].astype(np.float32), face_part[np.asarray(face)[idx]]
    counts = np.bincount(part_label, minlength=spec.num_parts)
    if counts.min() < cfg.min_part_points:
        p = int(counts.argmin())
        raise RejectedViewError(f"part {p} {spec.part_names[p]!r} keeps {int(counts[p])} < {cfg.min_part_points} "
                                "points")
    sample = ground_truth(spec, state, T_world_cam, motion, points, part_label, renderer.K)
    if cfg.cropped == "flag":
        sample["cropped"] = False
    return sample


def _submit_attempt(renderer: Renderer, spec: ArticulationSpec, cfg: RenderConfig, view: ViewConfig,
                    rng: np.random.Generator, state=None, T_world_cam=None) -> Frame:
    if state is None:
        state = _draw_state(spec, cfg, rng)
    if T_world_cam is None:
        T_world_cam = sample_camera_pose(view, spec.bbox_diag, rng)
    ground = cfg.sensor.kind == "realistic" and cfg.sensor.ground and view.viewpoints == "upright"
    return renderer.submit(spec, state, T_world_cam, rng, ground=ground, parts_alone=cfg.parts_alone)


def render_sample(
    renderer: Renderer,
    spec: ArticulationSpec,
    cfg: RenderConfig,
    view: ViewConfig,
    rng: np.random.Generator,
    state: np.ndarray | None = None,
    T_world_cam: np.ndarray | None = None,
    keep_images: bool = False,
) -> dict:
    """Render one view of ``spec`` (state and camera drawn with ``rng`` unless given).

    Returns the sample dict of :func:`process_frame`; raises as it does.
    """
    _submit_attempt(renderer, spec, cfg, view, rng, state, T_world_cam)
    return process_frame(renderer.fetch(), cfg, renderer.K, keep_images)


def _reason_key(reason: str) -> str:
    """Rejection reason without the numbers (for counting)."""
    return reason.split(" (")[0].split(" keeps")[0]


def _rejection_hint(reasons: Counter, cfg: RenderConfig) -> str:
    """What to change when every view of a sample was rejected, from the most frequent reason."""
    top = reasons.most_common(1)[0][0] if reasons else ""
    c = cfg.camera
    if top.startswith("too few object pixels"):
        return (f"the object covers fewer than {cfg.num_points} pixels of the {c.width} x {c.height} image: raise "
                "--width/--height, lower --points, or bring the camera closer (view distance range)")
    if top.startswith("object cropped"):
        return ("the object leaves the image in these views: raise the view distance range, or keep such views with "
                "--cropped flag (or keep)")
    if top.startswith("part"):
        return ("a part is hidden or too small in these views: lower --min-part-fraction (now "
                f"{cfg.min_part_fraction}) or change the view ranges so that every part is visible")
    return "change the view ranges or lower --min-part-fraction"


def render_many(
    renderer: Renderer,
    jobs: list[tuple[object, ArticulationSpec, tuple[int, ...]]],
    cfg: RenderConfig,
    view: ViewConfig,
    keep_images: bool = False,
):
    """Render many samples with one frame in flight; yields ``(key, sample, reasons)`` in job order.

    ``jobs`` are ``(key, spec, seed_key)``. Attempt ``a`` of a job uses
    ``np.random.default_rng((*seed_key, a))``; a rejected view is retried with the next attempt,
    so every sample depends only on its ``seed_key``. While the CPU back-projects, samples and
    labels frame k, the rasteriser already renders frame k+1. Each sample gets ``attempts``.

    Raises:
        RenderError: a job exhausted ``cfg.max_attempts`` views (names the object).
    """
    if cfg.complete:
        yield from _complete_many(renderer, jobs, cfg, view)
        return
    queue = [(i, 0) for i in range(len(jobs))]
    results: dict[int, tuple[dict, Counter]] = {}
    reasons: dict[int, Counter] = {i: Counter() for i in range(len(jobs))}
    next_out = 0
    pending_job = None
    while queue or pending_job is not None:
        if pending_job is None:
            i, a = queue.pop(0)
            _, spec, key = jobs[i]
            _submit_attempt(renderer, spec, cfg, view, np.random.default_rng((*key, a)))
            pending_job = (i, a)
        frame = renderer.fetch()
        done, pending_job = pending_job, None
        if queue:  # start the next picture before processing this one
            i2, a2 = queue.pop(0)
            _, spec2, key2 = jobs[i2]
            _submit_attempt(renderer, spec2, cfg, view, np.random.default_rng((*key2, a2)))
            pending_job = (i2, a2)
        i, a = done
        try:
            sample = process_frame(frame, cfg, renderer.K, keep_images)
        except RejectedViewError as e:
            reasons[i][_reason_key(e.reason)] += 1
            if a + 1 >= cfg.max_attempts:
                if pending_job is not None:
                    renderer.fetch()
                raise RenderError(f"{Path(jobs[i][1].urdf)}: all {cfg.max_attempts} sampled views were rejected "
                                  f"({dict(reasons[i])}); {_rejection_hint(reasons[i], cfg)}") from None
            queue.insert(0, (i, a + 1))
            continue
        sample["attempts"] = a + 1
        results[i] = (sample, reasons[i])
        while next_out in results:
            s, r = results.pop(next_out)
            yield jobs[next_out][0], s, r
            next_out += 1


def _complete_many(renderer: Renderer, jobs, cfg: RenderConfig, view: ViewConfig):
    """:func:`render_many` for the ``complete`` setting (:func:`sample_complete`): the same seeds per attempt."""
    for key, spec, seed_key in jobs:
        reasons = Counter()
        for a in range(cfg.max_attempts):
            try:
                sample = sample_complete(renderer, spec, cfg, view, np.random.default_rng((*seed_key, a)))
            except RejectedViewError as e:
                reasons[_reason_key(e.reason)] += 1
                continue
            sample["attempts"] = a + 1
            yield key, sample, reasons
            break
        else:
            raise RenderError(f"{Path(spec.urdf)}: all {cfg.max_attempts} complete samples were rejected "
                              f"({dict(reasons)}); {_rejection_hint(reasons, cfg)}")


def render_with_retries(
    renderer: Renderer, spec: ArticulationSpec, cfg: RenderConfig, view: ViewConfig, seed_key: tuple[int, ...],
    keep_images: bool = False,
) -> tuple[dict, Counter]:
    """Render one sample, drawing a new state and view after each rejection (see :func:`render_many`).

    Returns the sample (with ``attempts``) and a Counter of rejection reasons.
    """
    for _, sample, reasons in render_many(renderer, [(None, spec, seed_key)], cfg, view, keep_images):
        return sample, reasons
    raise AssertionError("unreachable")
