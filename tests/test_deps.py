"""Open3D imports with the libusb that the ``libusb-package`` wheel ships: pip alone is enough."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest


@pytest.mark.heavy
def test_open3d_links_against_the_wheels_libusb_when_asked():
    libusb_package = pytest.importorskip("libusb_package")
    wheel_copy = Path(libusb_package.get_library_path()).resolve()
    script = (
        "from lwbench import import_open3d\n"
        "o3d = import_open3d()\n"
        "o3d.geometry.PointCloud()\n"
        "maps = open('/proc/self/maps').read()\n"
        "print('\\n'.join(sorted({l.split()[-1] for l in maps.splitlines() if 'libusb' in l})))\n"
    )
    res = subprocess.run([sys.executable, "-c", script], env={"LWBENCH_LIBUSB": "package", "PATH": "/usr/bin:/bin"},
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    mapped = {Path(p).resolve() for p in res.stdout.split()}
    # The dynamic linker satisfied Open3D's libusb-1.0.so.0 with the copy loaded first: the wheel's.
    assert mapped == {wheel_copy}, mapped
