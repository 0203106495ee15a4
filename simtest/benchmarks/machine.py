"""What a benchmark records of the machine it ran on, so that a change of machine is not read as a change of
code: the processor's name (:func:`cpu_name`)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["cpu_name"]


def cpu_name(cpuinfo: str | Path = "/proc/cpuinfo") -> str:
    """The processor, as ``/proc/cpuinfo`` names it: its model name with the vendor's family and model numbers
    (``"AMD EPYC (family 26, model 2)"``; virtual machines often hide the full name, the numbers tell the
    generation apart); :func:`platform.processor` or ``"unknown"`` where that file is absent."""
    import platform

    fields: dict[str, str] = {}
    try:
        for line in Path(cpuinfo).read_text().splitlines():
            if not line.strip():
                break  # the first processor's block is enough
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
    except OSError:
        return platform.processor() or "unknown"
    name = fields.get("model name") or fields.get("Processor") or platform.processor() or "unknown"
    if "cpu family" in fields and "model" in fields:
        name += f" (family {fields['cpu family']}, model {fields['model']})"
    return name
