"""The keypoint estimator's checkpoint format (``simtest-keypoints/1``, the whole-image network) and its reader.

The file layout, the object-set record and the writer are shared by every learned estimator
(:mod:`simtest.estimators.checkpoint`); ``object_record``, ``check_objects``, ``save_checkpoint``,
``model_keypoints`` and ``GEOMETRY_TOL_M`` moved there and still import from here with a DeprecationWarning.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

from simtest.estimators import checkpoint as shared

__all__ = ["FORMAT", "load_checkpoint"]

FORMAT = "simtest-keypoints/1"
#: Names that moved to :mod:`simtest.estimators.checkpoint` (they import from here with a DeprecationWarning).
MOVED = {n: "simtest.estimators.checkpoint" for n in (
    "object_record", "check_objects", "save_checkpoint", "model_keypoints", "GEOMETRY_TOL_M")}


def __getattr__(name: str) -> Any:
    """The moved names (:data:`MOVED`), from their new module, with a DeprecationWarning."""
    if name in MOVED:
        warnings.warn(f"simtest.estimators.keypoints.checkpoint.{name} moved to {MOVED[name]}.{name}",
                      DeprecationWarning, stacklevel=2)
        return getattr(shared, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def load_checkpoint(path: str | Path, map_location: str = "cpu", fmt: str = FORMAT) -> dict[str, Any]:
    """Read a checkpoint with ``weights_only=True``; ``fmt`` is the expected ``format`` entry (the keypoint
    estimator's by default; see :func:`simtest.estimators.checkpoint.load_checkpoint`).

    Raises:
        ConfigError: Missing file, unreadable, or a checkpoint of another format.
    """
    return shared.load_checkpoint(path, map_location, fmt=fmt)
