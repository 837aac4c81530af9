"""A non-editable install (``pip install .``) carries the category templates: it builds assets anywhere."""

import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow


def test_wheel_install_builds_assets(tmp_path):
    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    target = tmp_path / "site"
    r = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q",
                        "--target", str(target), str(root)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert (target / "scapo" / "sim_assets" / "categories" / "laptop.toml").is_file()
    code = ("import scapo, sys; from scapo.sim.assets import build_instance; "
            f"assert scapo.__file__.startswith({str(target)!r}), scapo.__file__; "
            f"r = build_instance('laptop', 0, seed=0, cache_dir={str(tmp_path / 'cache')!r}); print(r.bbox_diag)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                       env={"PYTHONPATH": str(target), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert float(r.stdout.strip()) > 0
