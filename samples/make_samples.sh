#!/usr/bin/env bash
# Regenerate the files in samples/ (run from the repository root with hbvs installed).
# Every file here is used by at least one test; each stays under 2 MB.
set -euo pipefail
cd "$(dirname "$0")"
python - <<'PY'
import numpy as np
from hbvs_cli.core.camera import CameraIntrinsics
from hbvs_cli.core.path import PRESETS, sampled_profile
from hbvs_cli.io.calibration import save_calibration_ros

# A 320x240 camera (half the default resolution): keeps the sample recording small.
save_calibration_ros(CameraIntrinsics(fx=250.0, fy=250.0, cx=159.5, cy=119.5, width=320, height=240), "camera.yaml", camera_name="hbvs_sample")
# The default S-curve as a teach pendant sends it: 10 Hz, t,v,w.
preset = PRESETS["s-curve"]
profile = sampled_profile(preset.commands, preset.duration, 10.0)
np.savetxt("pendant.csv", np.column_stack([profile.t, profile.v, profile.w]), fmt="%.6f", delimiter=",", header="t,v,w", comments="")
PY
hbvs teach --path pendant.csv --calibration camera.yaml --fps 10 --format jpeg --noise 1 -o teach.mcap -q
hbvs fit teach.mcap -o fit.mcap -q
