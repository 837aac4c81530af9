"""``scapo doctor``: which Vulkan device SAPIEN renders on, and what to install if none."""

from __future__ import annotations

import glob
import os
import platform
import subprocess


def _mesa_version() -> str | None:
    try:
        out = subprocess.run(["dpkg-query", "-W", "-f=${Version}", "mesa-vulkan-drivers"], capture_output=True,
                             text=True, timeout=10)
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def diagnose() -> tuple[bool, list[str]]:
    """Try to render one picture; returns (ok, report lines)."""
    lines = [f"python {platform.python_version()} on {platform.platform()}"]
    icds = sorted(glob.glob("/usr/share/vulkan/icd.d/*.json") + glob.glob("/etc/vulkan/icd.d/*.json"))
    lines.append("Vulkan ICD files: " + (", ".join(os.path.basename(p) for p in icds) or "none"))
    mesa = _mesa_version()
    lines.append(f"mesa-vulkan-drivers: {mesa or 'not installed (dpkg)'}")
    try:
        import sapien
    except ImportError as e:
        lines.append(f"SAPIEN: not importable ({e}); run 'bash scripts/setup.sh'")
        return False, lines
    lines.append(f"SAPIEN {sapien.__version__}")
    try:
        import numpy as np

        from scapo.sim.render import CameraConfig, Renderer

        r = Renderer(CameraConfig(64, 64))
        b = r.scene.create_actor_builder()
        b.add_box_visual(half_size=[0.1, 0.1, 0.1])
        b.build_static(name="doctor_box")
        T = np.eye(4)
        T[:3, 3] = [0.0, 0.0, -1.0]  # camera 1 m in front of the box, looking along +z
        pts, _, valid = r.capture(T)
        summary = sapien.render.get_device_summary().strip().splitlines()
        lines.append("render device: " + (summary[0].strip() if summary else "unknown"))
        lines.append(f"test picture: {int(valid.sum())} of {valid.size} pixels hit a box 1 m away "
                     f"(depth {float(pts[valid][:, 2].mean()) if valid.any() else float('nan'):.3f} m, expected 0.9)")
        ok = bool(valid.any())
    except Exception as e:  # noqa: BLE001 - the point is to report it
        lines.append(f"rendering FAILED: {e}")
        ok = False
    if not ok:
        lines += [
            "What to install: SAPIEN 3 needs a Vulkan device.",
            "  CPU-only Debian bookworm: Mesa >= 24.3 from bookworm-backports, e.g.",
            "    echo 'deb http://deb.debian.org/debian bookworm-backports main' > /etc/apt/sources.list.d/bpo.list",
            "    apt-get update && apt-get install -t bookworm-backports mesa-vulkan-drivers libvulkan1",
            "  (or simply: bash scripts/setup.sh). Other systems: Mesa >= 24.3 lavapipe, or a GPU Vulkan driver.",
        ]
    return ok, lines
