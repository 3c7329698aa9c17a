"""Reads a capture file with y-tal 0.20.0's own reader (`tal.io.read_capture`), in y-tal's
venv (it pins numpy < 2), and returns what it saw: the test of "y-tal opens our files"."""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np

# Runs in .venv-ytal: read the capture with y-tal and dump what it saw.
READER = r"""
import json, sys
import numpy as np
import tal
from tal.io import read_capture
d = read_capture(sys.argv[1])
np.save(sys.argv[2], d.H)
np.save(sys.argv[3], d.sensor_grid_xyz)
np.save(sys.argv[4], d.laser_grid_xyz)
print(json.dumps({
    "tal_version": tal.__version__,
    "keys": sorted(k for k, v in d.as_dict().items() if v is not None),
    "H_format": d.H_format.name,
    "H_dtype": str(d.H.dtype),
    "sensor_grid_format": d.sensor_grid_format.name,
    "laser_grid_format": d.laser_grid_format.name,
    "is_confocal": bool(d.is_confocal()) if d.H_format.name == "T_Sx_Sy" else None,
    "delta_t": float(d.delta_t),
    "t_start": float(d.t_start),
    "t_accounts_first_and_last_bounces": bool(d.t_accounts_first_and_last_bounces),
    "sensor_xyz": np.asarray(d.sensor_xyz).tolist(),
    "laser_xyz": np.asarray(d.laser_xyz).tolist(),
    "scene_info": d.scene_info,
}))
"""


def read_with_ytal(python: str, path: Path, tmp: Path):
    h, s, l = tmp / "H.npy", tmp / "sensor.npy", tmp / "laser.npy"
    r = subprocess.run([python, "-c", READER, str(path), str(h), str(s), str(l)],
                       capture_output=True, text=True)
    assert r.returncode == 0, f"y-tal could not read {path}:\n{r.stderr}"
    return json.loads(r.stdout.strip().splitlines()[-1]), np.load(h), np.load(s), np.load(l)
