"""Hand-made detection results on ds_small: misses, duplicates, false positives, an estimate of a <10 % instance,
an absent object, tied scores, an image without estimates and one over the 100-estimate cut."""
import sys
import numpy as np
from pathlib import Path
from simtest.io.dataset import select_images
from simtest.io.bop_results import write_bop_results
from simtest.metrics.bop19 import ResultRow
from simtest.estimators.oracle import axis_angle_matrix

root = Path(sys.argv[1]); out = Path(sys.argv[2])
refs = {(r.scene_id, r.im_id): r for r in select_images(root, "train_pbr", None, None, [1, 7, 13, 22])}
rows = []

def gt(s, i, k):
    g = refs[(s, i)].info["gt"][k]
    return g.T_cam_obj.R, g.T_cam_obj.t, g.obj_id

def add(s, i, k, score, rot_deg=0.0, axis=(0, 0, 1), dt_mm=(0, 0, 0), obj=None):
    R, t, o = gt(s, i, k)
    ax = np.asarray(axis, float); ax /= np.linalg.norm(ax)
    R = axis_angle_matrix(ax, np.radians(rot_deg)) @ R
    rows.append(ResultRow(s, i, o if obj is None else obj, score, R, t + np.asarray(dt_mm) / 1000.0, 0.25))

# scene 0 image 0: objects 1, 22, 13, 22, 7, 13
add(0, 0, 0, 0.9)                                   # exact
add(0, 0, 1, 0.8, dt_mm=(5, 0, 0))                  # 5 mm off
add(0, 0, 1, 0.85, dt_mm=(0, 3, 0))                 # duplicate of the same instance
add(0, 0, 2, 0.7, rot_deg=20, axis=(1, 1, 0))       # 20 degrees off; instance 5 (obj 13) missed
add(0, 0, 4, 0.6, dt_mm=(30, 0, 10))                # 32 mm off
add(0, 0, 5, 0.95, dt_mm=(400, 0, 0), obj=13)       # false positive far away
# scene 0 image 1: objects 1, 22, 13, 22, 7 (visib 0.08), 13
add(0, 1, 4, 0.99)                                  # exact on a <10 % instance: ignored
add(0, 1, 0, 0.5)
add(0, 1, 1, 0.9); add(0, 1, 3, 0.9)                # tied scores
add(0, 1, 2, 0.9, dt_mm=(10, 0, 0))
add(0, 1, 5, 0.3, rot_deg=60, axis=(0, 1, 0))       # far off in rotation
# scene 0 image 2: objects 1, 22, 13, 22, 7 (visib 0.0), 13
add(0, 2, 4, 0.7, dt_mm=(0, 0, 200))                # off a hidden instance: a false positive
add(0, 2, 2, 0.4, dt_mm=(2, 2, 2)); add(0, 2, 5, 0.45, rot_deg=3, axis=(0, 0, 1))
add(0, 2, 1, 0.6, rot_deg=8, axis=(1, 0, 0), dt_mm=(4, 0, 0)); add(0, 2, 3, 0.2, dt_mm=(15, 15, 0))
add(0, 2, 0, 0.65, rot_deg=180, axis=(0, 0, 1))
# scene 1 image 0: objects 7, 7, 7, 1, 22, 22
add(1, 0, 0, 0.9); add(1, 0, 1, 0.8, dt_mm=(8, 0, 0)); add(1, 0, 2, 0.7, rot_deg=12, axis=(0, 1, 1))
add(1, 0, 1, 0.75, dt_mm=(0, 1, 0))                 # duplicate
add(1, 0, 4, 0.6, rot_deg=5, axis=(1, 0, 0)); add(1, 0, 5, 0.55, rot_deg=40, axis=(0, 0, 1))
add(1, 0, 0, 0.99, obj=13)                          # object 13 is not in this image
# scene 1 image 1: no estimates
# scene 1 image 2: 103 low-score false positives, one true positive below the 100-estimate cut
for n in range(103):
    add(1, 2, n % 6, 0.5 - n * 0.001, dt_mm=(300 + n, -200, 0))
add(1, 2, 3, 0.9); add(1, 2, 4, 0.88, dt_mm=(3, 3, 3))
add(1, 2, 0, 0.0001)                                # cut
write_bop_results(out, rows)
print(len(rows), "rows")
