"""The networks shipped in ``simtest/estimators/weights/``, chosen by the objects they were trained for.

A shipped network is a pair ``<family>_<object set>_<W>x<H>[.<variant>].pt`` / ``.onnx`` (e.g.
``keypoints_lmo_640x480.onnx``: the keypoint crop network of LM-O's eight objects, trained on 640x480 images;
``keypoints_detector_lmo_640x480.clutter.onnx``: a second LM-O detector, trained on other data).
The ONNX file carries the object record the network was trained for (ids, mesh hashes, vertex counts, bounding
boxes; :func:`simtest.estimators.keypoints.checkpoint.object_record`), so an estimator given no checkpoint
takes the shipped file whose record matches the objects it is asked about: the models' content decides, not a
folder's name (:func:`choose`; :func:`choose_all` for every match, e.g. the detectors whose regions are
pooled). Objects that no shipped network knows get a :class:`ConfigError` that names the shipped sets and why
each does not match.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

from simtest.errors import ConfigError
from simtest.estimators.checkpoint import check_objects

__all__ = ["ShippedNet", "weights_dir", "shipped_nets", "choose", "choose_all", "matches", "POSE_STAGES", "pose_stage"]

#: The pose stage of the ``keypoints`` estimator for a shipped object set where it is not the set's crop
#: network (``network``): on LM-O's real photographs the template matcher
#: (:mod:`simtest.estimators.templates`) on the shipped detector's regions poses far more objects correctly
#: than the crop network trained on renders (docs/sim2real.md).
POSE_STAGES = {"lmo": "templates"}

_NAME = re.compile(r"^(?P<family>[a-z_]+?)_(?P<set>[A-Za-z0-9.-]+?)_(?P<w>\d+)x(?P<h>\d+)"
                   r"(?:\.(?P<variant>[a-z0-9-]+))?\.onnx$")


@dataclass(frozen=True)
class ShippedNet:
    """One shipped network: ``path`` (the ``.pt`` file; its ``.onnx`` beside it), the ``object_set`` of its name,
    its training image size ``(width, height)`` in pixels, the object ``record`` it was trained for and the
    ``variant`` of its name ("" for the set's first network)."""

    path: Path
    family: str
    object_set: str
    size: tuple[int, int]
    record: dict[str, Any]
    variant: str = ""


def weights_dir() -> Path:
    """The folder of the shipped networks (inside the installed package)."""
    return Path(__file__).resolve().parent / "weights"


@lru_cache(maxsize=None)
def _record(onnx_path: Path, fmt: str) -> dict[str, Any] | None:
    """The object record of a shipped ONNX file of format ``fmt`` (None for another format)."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.log_severity_level = 3
    meta = ort.InferenceSession(str(onnx_path), so, providers=["CPUExecutionProvider"]).get_modelmeta()
    raw = meta.custom_metadata_map
    if raw.get("simtest.format") != fmt or "simtest.objects" not in raw:
        return None
    return json.loads(raw["simtest.objects"])


def shipped_nets(family: str, fmt: str, folder: Path | None = None) -> list[ShippedNet]:
    """The shipped networks of one family (``keypoints``, ``keypoints_detector``, ``segicp``) and checkpoint
    format, sorted by object set, size and variant (a set's network without a variant first)."""
    folder = weights_dir() if folder is None else Path(folder)
    out = []
    for onnx in folder.glob(f"{family}_*.onnx"):
        m = _NAME.match(onnx.name)
        if m is None or m["family"] != family:
            continue
        rec = _record(onnx.resolve(), fmt)
        if rec is not None:
            out.append(ShippedNet(onnx.with_suffix(".pt"), family, m["set"], (int(m["w"]), int(m["h"])), rec,
                                  m["variant"] or ""))
    return sorted(out, key=lambda n: (n.object_set, n.size, n.variant))


def matches(record: dict[str, Any], objects: Any, subset: bool = False) -> str | None:
    """None when ``objects`` is the set ``record`` was trained for, else why not (one line).

    ``subset``: the network needs only its own objects among ``objects`` (a detector looks for its classes and
    ignores others)."""
    ids = [int(i) for i in record["obj_ids"]]
    if subset and set(ids) <= {int(i) for i in getattr(objects, "ids", [])}:
        objects = objects.subset(ids)
    try:
        check_objects(record, objects, where="it", hint="")
    except ConfigError as exc:
        return str(exc).strip().rstrip(".")
    return None


def pose_stage(net: ShippedNet) -> str:
    """``network`` (the crop network) or ``templates``: how the ``keypoints`` estimator poses the objects of
    the shipped network ``net`` when no ``pose`` option is given (:data:`POSE_STAGES`)."""
    return POSE_STAGES.get(net.object_set, "network")


def choose(family: str, fmt: str, objects: Any, *, what: str, subset: bool = False,
           folder: Path | None = None) -> ShippedNet:
    """The shipped network of ``family`` trained for ``objects`` (compared by content: ids and meshes); the
    first of :func:`choose_all`."""
    return choose_all(family, fmt, objects, what=what, subset=subset, folder=folder)[0]


def choose_all(family: str, fmt: str, objects: Any, *, what: str, subset: bool = False,
               folder: Path | None = None) -> list[ShippedNet]:
    """Every shipped network of ``family`` trained for ``objects``, in :func:`shipped_nets`' order (a set's
    network without a variant first).

    Raises:
        ConfigError: No shipped network of the family knows these objects; the message names each shipped set
            and what differs, and how to train one.
    """
    found, reasons = [], []
    for net in shipped_nets(family, fmt, folder):
        why = matches(net.record, objects, subset)
        if why is None:
            found.append(net)
        else:
            reasons.append(f"{net.path.with_suffix('.onnx').name} ({net.object_set}): {why}")
    if found:
        return found
    shipped = "; ".join(reasons) if reasons else f"none found in {weights_dir()}"
    raise ConfigError(f"{what}: no shipped network was trained for these objects. Shipped: {shipped}. Train one "
                      "(simtest generate --objects SET ...; simtest train ...) and pass --opt checkpoint=RUN/model.pt")
