"""``scapo view``: an interactive 3-D viewer in the browser (viser) for datasets, predictions and twins.

Built on viser (Yi et al., a library for 3-D vision and robotics visualisation in the browser): the server
holds the scene, any browser that opens its URL shows it. In the scene:

- the sample's cloud, coloured by ground-truth part or by the part of a prediction (``--pred``, several
  allowed; slots matched to GT parts by point IoU on the sample, as the figures do), in the camera frame turned
  so that the camera's -y is up;
- the GT joint axes (black) and the selected prediction's (magenta) with their pivots (dots), drawn at
  :func:`~scapo.sim.preview.axis_anchor`;
- with ``--twin``, the exported twin (:mod:`scapo.twin.export`) as meshes placed by its predicted pose in the view
  it was exported from (the viewer starts at that sample), and one slider per joint that articulates it (forward
  kinematics of its URDF).

GUI: a sample slider, a dropdown of what colours the points, checkboxes for the axes. The samples are those of
``--split`` (default test).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from scapo.data.dataset import load
from scapo.errors import ConfigError
from scapo.eval.predictions import Predictions
from scapo.sim.preview import axis_anchor, part_colors

#: Display rotation: camera frame (x right, y down, z forward) to viser's world (z up): x -> x, y -> -z, z -> y.
R_VIEW = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def _matched(pred_label: np.ndarray, gt_label: np.ndarray, parts: int) -> np.ndarray:
    from scapo.eval.metrics import match_parts

    S = int(pred_label.max()) + 1 if pred_label.size and pred_label.max() >= 0 else 1
    slot_of = match_parts(pred_label, gt_label, parts, max(S, parts))
    table = np.full(max(S, parts), -1, dtype=np.int64)
    for p, s in enumerate(slot_of):
        if s >= 0:
            table[s] = p
    return np.where(pred_label >= 0, table[np.maximum(pred_label, 0)], -1)


def check_listen_address(host: str, port: int) -> None:
    """Refuse, before a server starts, a port outside 1..65535, a host this machine cannot listen on (not one of
    its addresses or a resolvable name), and a port already taken.

    Raises:
        ConfigError: naming the problem and a working example."""
    import socket

    from scapo.errors import ConfigError

    if not isinstance(port, int) or not 1 <= port <= 65535:
        raise ConfigError(f"--port {port}: a port is a number in 1..65535 (e.g. --port 8080)")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as e:
        raise ConfigError(f"--host {host!r} is not an address or name this machine knows ({e.strerror or e}); use "
                          "127.0.0.1 (this machine) or 0.0.0.0 (every interface)") from None
    family, _, _, _, addr = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
        except OSError as e:
            raise ConfigError(f"cannot listen on {host}:{port} ({e.strerror or e}); choose another --port, or "
                              "--host 127.0.0.1") from None


class Viewer:
    """The viewer's state and scene (see the module docstring).

    Args:
        data: dataset folder. predictions: predictions files of it. twin: a twin folder. split: which samples.
        host, port: where the server listens.

    Raises:
        DatasetError: ``data`` is not a dataset or the split is empty. PredictionError: a predictions file that
        does not cover the split. ConfigError: viser is not installed.
    """

    def __init__(self, data: str | Path, predictions=(), twin: str | Path | None = None, split: str = "test",
                 host: str = "127.0.0.1", port: int = 8080):
        try:
            import viser
        except ImportError:
            raise ConfigError("scapo view needs viser: pip install viser") from None
        self.ds = load(data, split)
        if len(self.ds) == 0:
            raise ConfigError(f"the {split} split of {data} is empty; choose another --split")
        self.split = split
        self.preds = [Predictions.load(p) for p in predictions]
        for path, p in zip(predictions, self.preds):  # the evaluator's rule: predictions of this dataset only
            if p.dataset_hash != self.ds.dataset_hash:
                raise ConfigError(f"--pred {path} was made on dataset {p.dataset_hash[:12] or '(none named)'}, not "
                                  f"on {data} ({self.ds.dataset_hash[:12]}); predict on this dataset first")
        self.rows = []
        for p in self.preds:
            index = {(int(i), int(v), str(s)): k for k, (i, v, s) in enumerate(zip(p.instance_id, p.view_id, p.split))}
            rows = [index.get((i, v, split), -1) for i, v in self.ds.keys()]
            if min(rows) < 0:
                from scapo.errors import PredictionError

                raise PredictionError(f"predictions {p.method!r} do not cover the {split} split of {data}")
            self.rows.append(rows)
        check_listen_address(host, port)
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        # start where the camera was: behind the cloud's centre (-y in the display frame), a little above
        d = float(self.ds[0]["bbox_diag"])
        self.server.initial_camera.position = (0.0, -1.8 * d, 0.35 * d)
        self.server.initial_camera.look_at = (0.0, 0.0, 0.0)
        self.twin = None
        first = 0
        if twin is not None:  # start at the twin's own sample
            import json

            first = int(json.loads((Path(twin) / "twin.json").read_text())["sample"])
        gui = self.server.gui
        self.sample = gui.add_slider("sample", min=0, max=len(self.ds) - 1, step=1, initial_value=first)
        self.colour = gui.add_dropdown("colour by", options=["ground truth", *[p.method for p in self.preds]],
                                       initial_value="ground truth")
        self.show_gt = gui.add_checkbox("GT joint axes", True)
        self.show_pred = gui.add_checkbox("predicted joint axes", bool(self.preds))
        for h in (self.sample, self.colour, self.show_gt, self.show_pred):
            h.on_update(lambda _: self.draw())
        self.draw()
        if twin is not None:
            self._load_twin(Path(twin))

    # ------------------------------------------------------------------ drawing
    def draw(self) -> None:
        """(Re)draw the current sample."""
        k = int(self.sample.value)
        item = self.ds[k]
        pts = item["points"].astype(np.float64)
        gt = item["part_label"]
        labels = gt
        pi = None
        if self.colour.value != "ground truth":
            pi = [p.method for p in self.preds].index(self.colour.value)
            labels = _matched(self.preds[pi].part_label[self.rows[pi][k]], gt, self.ds.num_parts)
        elif self.preds:
            pi = 0
        scene = self.server.scene
        diag = float(item["bbox_diag"])
        scene.add_point_cloud("/cloud", (pts - pts.mean(0)) @ R_VIEW.T, part_colors(labels).astype(np.float32),
                              point_size=0.006 * diag, point_shape="circle")
        self._axes("/gt_axes", item["joint_type"], item["joint_axis"], item["joint_pivot"], pts[gt >= 0], pts,
                   (20, 20, 20), self.show_gt.value, diag)
        if pi is not None:
            p, r = self.preds[pi], self.rows[pi][k]
            self._axes("/pred_axes", p.joint_type[r], p.joint_axis[r], p.joint_pivot[r], pts[gt >= 0], pts,
                       (200, 0, 200), self.show_pred.value, diag)

    def _axes(self, name, types, axes, pivots, obj, pts, color, visible, diag) -> None:
        segs, anchors = [], []
        for t, a, c in zip(types, axes, pivots):
            c = axis_anchor(int(t), a, c, obj)
            anchors.append(c)
            segs.append([c - 0.3 * diag * np.asarray(a), c + 0.3 * diag * np.asarray(a)])
        if not segs:
            return
        segs = (np.asarray(segs) - pts.mean(0)) @ R_VIEW.T
        self.server.scene.add_line_segments(name, segs.astype(np.float32), np.array(color, dtype=np.uint8),
                                            thickness=0.01 * diag, visible=bool(visible))
        # the pivots (prismatic joints: where the slide is drawn)
        self.server.scene.add_point_cloud(f"{name}_pivots", ((np.asarray(anchors) - pts.mean(0)) @ R_VIEW.T)
                                          .astype(np.float32), np.array(color, dtype=np.uint8),
                                          point_size=0.03 * diag, point_shape="circle", visible=bool(visible))

    # ------------------------------------------------------------------ twin
    def _load_twin(self, folder: Path) -> None:
        import json

        import trimesh

        from scapo.sim.assets.urdf import load_part_mesh, load_partnet_mobility

        spec = load_partnet_mobility(folder)
        info = json.loads((folder / "twin.json").read_text())
        centre = self.ds[int(info["sample"])]["points"].astype(np.float64).mean(0)  # as the cloud of that sample
        self.twin = {"spec": spec, "T_cam_root": np.asarray(info["T_cam_root"]), "meshes": [], "centre": centre,
                     "state": np.array([j["state"] for j in info["joints"]]) - [j.rest_qpos for j in spec.gt_joints]}
        gui = self.server.gui
        folder_gui = gui.add_folder("twin joints")
        with folder_gui:
            self.twin["sliders"] = []
            for j, joint in enumerate(spec.gt_joints):
                lo, hi = (float(x) for x in joint.limit)
                s = gui.add_slider(joint.name, min=lo, max=hi, step=(hi - lo) / 200 or 0.01,
                                   initial_value=float(np.clip(self.twin["state"][j], lo, hi)))
                s.on_update(lambda _: self._draw_twin())
                self.twin["sliders"].append(s)
        for p in range(spec.num_parts):
            mesh = load_part_mesh(spec, p)  # at rest, in the twin's object frame
            self.twin["meshes"].append(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False))
        self._draw_twin()

    def _draw_twin(self) -> None:
        """The twin's parts at the sliders' state, in the observed camera (as the cloud)."""
        spec = self.twin["spec"]
        state = np.array([float(s.value) for s in self.twin["sliders"]])
        poses = spec.link_poses(state)
        from scapo.ops.rigid import invert_transform, transform_points
        from scapo.sim.render import part_link_names

        T_cam_obj = self.twin["T_cam_root"] @ invert_transform(spec.T_obj_root)
        for p, link in enumerate(part_link_names(spec)):
            motion = poses[link] @ invert_transform(spec.rest_link_poses[link])
            v = transform_points(T_cam_obj @ motion, self.twin["meshes"][p].vertices) - self.twin["centre"]
            self.server.scene.add_mesh_simple(f"/twin/part{p}", (v @ R_VIEW.T).astype(np.float32),
                                              self.twin["meshes"][p].faces.astype(np.uint32),
                                              color=tuple(int(255 * c) for c in part_colors(np.array([p]))[0]),
                                              opacity=0.5)

    # ------------------------------------------------------------------ serving
    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    def serve_forever(self) -> None:
        """Block until Ctrl-C, then stop the server."""
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
        finally:
            self.server.stop()
