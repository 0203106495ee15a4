"""A guard against silent slow-downs: a fresh ``simtest bench generate --profiles`` run against the figures
recorded in the repository (:data:`RECORDED`), as ratios.

``simtest bench generate --profiles ... --json FILE`` writes its table as JSON (:func:`bench_record`: the rows,
the command's parameters, the machine's cores and load average). ``simtest bench check`` runs the same
measurement again (or reads a fresh ``--json`` file) and prints, for every recorded profile and image size,
fresh / recorded seconds per frame (wall and CPU); a ratio above the tolerance is a slow-down. A shared machine's
load moves wall time most: compare runs made under similar load (both are printed), and re-record after a
deliberate change (``--json simtest/benchmarks/recorded.json``). Each record names its processor
(:func:`simtest.benchmarks.machine.cpu_name`); when the two differ the table says so, since the ratios then
compare machines, not code (the same code ran 0.6x as long on a Zen 5 EPYC as on the host its first figures
were recorded on).
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

from simtest.benchmarks.machine import cpu_name
from simtest.errors import ConfigError

__all__ = ["RECORDED", "CheckRow", "bench_record", "compare", "check_table", "read_record", "fresh_record"]

#: The figures recorded in the repository (a :func:`bench_record` of the pbr profile at 320x240 and 640x480).
RECORDED = Path(__file__).with_name("recorded.json")
MEASURES = ("wall", "cpu")


@dataclass(frozen=True)
class CheckRow:
    """One profile at one image size: recorded and fresh seconds per frame and their ratios (fresh / recorded).

    Attributes:
        ok: The ratio of the measure checked is at most the tolerance (``None``: not in the fresh run).
    """

    profile: str
    width: int
    height: int
    recorded_wall: float
    fresh_wall: float | None
    recorded_cpu: float
    fresh_cpu: float | None
    ok: bool | None

    @property
    def wall_ratio(self) -> float | None:
        return None if self.fresh_wall is None else self.fresh_wall / self.recorded_wall

    @property
    def cpu_ratio(self) -> float | None:
        return None if self.fresh_cpu is None else self.fresh_cpu / self.recorded_cpu


def bench_record(table: dict, command: str = "") -> dict:
    """``table`` (a :meth:`ProfileBench.to_dict` or :meth:`GenerateBench.to_dict`) with what the run saw: the
    command, the processor (:func:`simtest.benchmarks.machine.cpu_name`), cores, the load averages (1, 5 and 15
    minutes) when it is written and the time (UTC)."""
    from simtest.backend.threads import available_cores

    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    return {**table, "command": command, "machine": {
        "cpu": cpu_name(), "cores": available_cores(), "load_average_1_5_15": [round(x, 2) for x in load],
        "recorded_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}}


def read_record(path: str | Path) -> dict:
    """A :func:`bench_record` JSON file of a ``--profiles`` run.

    Raises:
        ConfigError: If the file is missing, not JSON, or not a profiles table (naming the file).
    """
    p = Path(path)
    try:
        rec = json.loads(p.read_text())
    except FileNotFoundError:
        raise ConfigError(f"benchmark record {str(p)!r} does not exist") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(f"benchmark record {str(p)!r} is not JSON ({exc})") from None
    if not isinstance(rec, dict) or rec.get("kind") != "profiles" or not isinstance(rec.get("rows"), list):
        raise ConfigError(f"benchmark record {str(p)!r} is not a `simtest bench generate --profiles ... --json` "
                          f"table (kind {rec.get('kind') if isinstance(rec, dict) else None!r})")
    return rec


def compare(recorded: dict, fresh: dict, tolerance: float = 1.3, measure: str = "cpu") -> list[CheckRow]:
    """Every row of ``recorded`` beside the fresh run's row of the same profile and image size.

    Args:
        recorded, fresh: Profiles tables (:func:`read_record`).
        tolerance: Largest fresh / recorded ratio of ``measure`` that passes (> 0).
        measure: ``"cpu"`` (CPU seconds per frame, less moved by other work on the machine) or ``"wall"``.

    Raises:
        ConfigError: Naming a bad ``tolerance`` or ``measure``.
    """
    if measure not in MEASURES:
        raise ConfigError(f"measure {measure!r} is unknown; allowed: {', '.join(MEASURES)}")
    if not tolerance > 0:
        raise ConfigError(f"tolerance must be > 0, got {tolerance!r}")
    now = {(r["profile"], r["width"], r["height"]): r for r in fresh["rows"]}
    out = []
    for r in recorded["rows"]:
        f = now.get((r["profile"], r["width"], r["height"]))
        fw, fc = (None, None) if f is None else (float(f["wall"]), float(f["cpu"]))
        ratio = None if f is None else (fw / r["wall"] if measure == "wall" else fc / r["cpu"])
        out.append(CheckRow(r["profile"], r["width"], r["height"], float(r["wall"]), fw, float(r["cpu"]), fc,
                            None if ratio is None else ratio <= tolerance))
    return out


def check_table(rows: list[CheckRow], recorded: dict, fresh: dict, tolerance: float, measure: str) -> str:
    """The comparison as a Markdown table, with both runs' load averages."""
    def fmt(x: float | None, spec: str = ".2f") -> str:
        return "-" if x is None else format(x, spec)

    lines = [f"| profile | image size | recorded s/frame (wall; CPU) | fresh s/frame (wall; CPU) | fresh / recorded: "
             f"wall | CPU | within {tolerance:.2f} ({measure}) |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        verdict = "-" if r.ok is None else ("yes" if r.ok else "NO: slower")
        lines.append(f"| {r.profile} | {r.width}x{r.height} | {r.recorded_wall:.2f}; {r.recorded_cpu:.2f} | "
                     f"{fmt(r.fresh_wall)}; {fmt(r.fresh_cpu)} | {fmt(r.wall_ratio)} | {fmt(r.cpu_ratio)} | "
                     f"{verdict} |")
    loads = [d.get("machine", {}).get("load_average_1_5_15") for d in (recorded, fresh)]
    cpus = [d.get("machine", {}).get("cpu") for d in (recorded, fresh)]
    lines += ["", f"load average (1, 5, 15 min) when written: recorded {loads[0]}, fresh {loads[1]}",
              f"processor: recorded {cpus[0] or 'not recorded'}, fresh {cpus[1] or 'not recorded'}"]
    if cpus[0] != cpus[1]:
        lines.append("NOTE: the runs are not known to be on the same processor, so the ratios compare machines as "
                     "well as code; re-record on this machine (`simtest bench generate ... --json "
                     "simtest/benchmarks/recorded.json`) before reading them as a change of the code")
    return "\n".join(lines)


def fresh_record(recorded: dict) -> dict:
    """A new profiles run with the recorded run's profiles, image sizes, scenes and views (1 worker; the pbr
    profile at ``render.pbr_spp = "auto"``, as the recorded figures)."""
    from simtest.benchmarks.generate import bench_profiles

    rows = recorded["rows"]
    profiles = list(dict.fromkeys(r["profile"] for r in rows))
    sizes = list(dict.fromkeys((int(r["width"]), int(r["height"])) for r in rows))
    res = bench_profiles(profiles, sizes, scenes=int(recorded["scenes"]),
                         frames_per_scene=int(recorded["frames_per_scene"]), two_workers=False)
    return bench_record(res.to_dict(), "simtest bench check")
