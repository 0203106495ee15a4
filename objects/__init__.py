"""Objects: ``ObjectModel`` / ``ObjectSet``, built-in procedural categories, mesh and BOP-model loaders,
symmetries (declared or detected), grasp candidates and collision geometry.

Typical use::

    from simtest.objects import load_object_set
    objects = load_object_set("builtin")          # or "builtin-small", a mesh folder, a BOP models folder
    mug = objects.get(7)
    mug.grasps.best(5)                            # antipodal grasp candidates in the model frame
"""

from simtest.objects.builtin import BUILTIN_SETS, load_builtin
from simtest.objects.grasps import PANDA, Gripper, GraspSet, sample_grasps
from simtest.objects.loaders import load_mesh_file, load_mesh_folder, load_object_set, read_bop_models
from simtest.objects.model import ContinuousSymmetry, ObjectModel, ObjectSet
from simtest.objects.symmetry_detect import detect_symmetries

__all__ = [
    "BUILTIN_SETS",
    "ContinuousSymmetry",
    "GraspSet",
    "Gripper",
    "ObjectModel",
    "ObjectSet",
    "PANDA",
    "detect_symmetries",
    "load_builtin",
    "load_mesh_file",
    "load_mesh_folder",
    "load_object_set",
    "read_bop_models",
    "sample_grasps",
]
