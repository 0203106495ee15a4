"""Where a path-traced frame's time goes: wall seconds per stage of :class:`simtest.render.pbr.PbrRenderer`.

Stages (:data:`STAGES`), in the order a frame runs them:

* ``scene``: the scene key of the MuJoCo state and, when it changed, building and loading the Mitsuba scene
  (geometry, materials and textures, emitters; once per settled scene, every view after the first reuses it);
* ``sensor``: the view's camera as a Mitsuba sensor;
* ``trace``: path tracing (the kernel's tracing and compilation or kernel-cache lookup, and reading the image
  back);
* ``guides``: the albedo / normal guide pass of the denoiser;
* ``denoise``: Open Image Denoise;
* ``image``: resampling onto the image grid and the sRGB encoding.

Every renderer adds its times to its own :class:`StageTimes` and to this process's (:func:`process_stages`),
which ``simtest bench generate --profiles pbr`` reads around a one-worker run.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Iterator

__all__ = ["STAGES", "StageTimes", "process_stages"]

STAGES: tuple[str, ...] = ("scene", "sensor", "trace", "guides", "denoise", "image")


@dataclass
class StageTimes:
    """Wall seconds spent in each stage (:data:`STAGES`), frames rendered and Mitsuba scenes loaded.

    Attributes:
        seconds: Stage name -> wall seconds, summed over frames.
        frames: Frames rendered.
        loads: Mitsuba scenes built and loaded (views of an unchanged scene reuse the loaded one).
    """

    seconds: dict[str, float] = field(default_factory=lambda: dict.fromkeys(STAGES, 0.0))
    frames: int = 0
    loads: int = 0

    @contextmanager
    def stage(self, name: str, *also: "StageTimes") -> Iterator[None]:
        """Time the ``with`` block as stage ``name`` here and in each of ``also``.

        Raises:
            KeyError: If ``name`` is not one of :data:`STAGES` (the message lists them).
        """
        if name not in self.seconds:
            raise KeyError(f"unknown pbr stage {name!r}; stages: {', '.join(STAGES)}")
        t0 = time.perf_counter()
        try:
            yield
        finally:
            dt = time.perf_counter() - t0
            for t in (self, *also):
                t.seconds[name] = t.seconds.get(name, 0.0) + dt

    def copy(self) -> "StageTimes":
        return StageTimes(dict(self.seconds), self.frames, self.loads)

    def since(self, earlier: "StageTimes") -> "StageTimes":
        """What was added after ``earlier`` (a :meth:`copy` of this one taken before)."""
        return StageTimes({k: v - earlier.seconds.get(k, 0.0) for k, v in self.seconds.items()},
                          self.frames - earlier.frames, self.loads - earlier.loads)

    def add(self, other: "StageTimes") -> None:
        """Add ``other``'s seconds, frames and loads to this one."""
        for k, v in other.seconds.items():
            self.seconds[k] = self.seconds.get(k, 0.0) + v
        self.frames += other.frames
        self.loads += other.loads

    def per_frame(self) -> dict[str, float]:
        """Stage name -> wall seconds per frame (zeros before the first frame)."""
        n = max(1, self.frames)
        return {k: v / n for k, v in self.seconds.items()}

    @property
    def total(self) -> float:
        """Wall seconds over every stage."""
        return float(sum(self.seconds.values()))


_PROCESS = StageTimes()


def process_stages() -> StageTimes:
    """The stage times of every :class:`simtest.render.pbr.PbrRenderer` of this process (a live object: take a
    :meth:`StageTimes.copy` before and :meth:`StageTimes.since` after the work to measure)."""
    return _PROCESS
