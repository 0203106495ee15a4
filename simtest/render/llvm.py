"""The path tracer's Mitsuba variant (CUDA, LLVM or scalar) and the libLLVM its LLVM variant loads.

:func:`choose_variant` resolves ``render.pbr_variant``. :func:`find_libllvm` finds a libLLVM that Mitsuba's
LLVM variant can use (LLVM >= 16) without loading it into this process.

Dr.Jit loads libLLVM when ``drjit`` is imported (not when a variant is chosen), from ``DRJIT_LIBLLVM_PATH`` or
else its own search of ``/usr/lib/{x86_64,aarch64}-linux-gnu/libLLVM*.so.*``. It accepts LLVM 15, but Mitsuba's
kernels then abort the whole process at the first render (LLVM's instruction selection: "Cannot select ...
fminimum"), which no ``try`` can catch. So simtest chooses the library itself, before ``drjit`` is imported:

* ``DRJIT_LIBLLVM_PATH`` when the user set it (then it is the only candidate, and it is checked);
* else the newest major >= :data:`MIN_MAJOR` in :data:`SEARCH_DIRS`, which :func:`point_drjit_at` then puts in
  ``DRJIT_LIBLLVM_PATH`` so Dr.Jit's own search (which may pick 15) is not used.

The major version is read from the file without loading it: the ELF ``DT_SONAME`` (``libLLVM-15.so.1``,
``libLLVM.so.19.1``), else the ELF symbol-version names (``LLVM_19.1``), else the file name; an unversioned
name such as ``/usr/lib/llvm-14/lib/libLLVM.so`` is read from its soname.
"""

from __future__ import annotations

import gc
import glob
import logging
import os
import re
import struct
import sys
import zlib
from dataclasses import dataclass

__all__ = ["LibLLVM", "MIN_MAJOR", "ENV", "SEARCH_DIRS", "INSTALL_LLVM", "llvm_major", "find_libllvm", "without_gc",
           "point_drjit_at", "PBR_VARIANTS", "Variant", "choose_variant", "note_once"]

#: Oldest LLVM major Mitsuba's LLVM variant runs with (15 aborts the process at the first render).
MIN_MAJOR = 16
#: The environment variable Dr.Jit reads at import for the libLLVM to load.
ENV = "DRJIT_LIBLLVM_PATH"
#: Library folders searched, in order (globs); the newest major found wins.
SEARCH_DIRS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib",
               "/usr/local/lib", "/usr/lib/llvm-*/lib")
#: What to install when no usable libLLVM is found.
INSTALL_LLVM = (f"install LLVM >= {MIN_MAJOR}: 'apt-get install libllvm19' on Debian/Ubuntu; elsewhere the "
                f"distribution's LLVM >= {MIN_MAJOR} shared library, then set {ENV} to its libLLVM*.so file")

_NAME_RES = (re.compile(r"^libLLVM-(\d+)(?:\.\d+)*(?:git)?\.so(?:\.\d+)*$"),  # libLLVM-15.so.1, libLLVM-14.0.6.so
             re.compile(r"^libLLVM\.so\.(\d+)(?:\.\d+)*$"))  # libLLVM.so.19.1
_VERSION_DEF = re.compile(rb"\x00LLVM_(\d+)(?:\.\d+)*\x00")
_SHT_DYNAMIC, _DT_NULL, _DT_SONAME = 6, 0, 14


@dataclass(frozen=True)
class LibLLVM:
    """The outcome of :func:`find_libllvm`.

    Attributes:
        path: The library to load (``None``: no usable one).
        major: Its LLVM major version, or that of the newest library refused (``None`` if none was read).
        how: Where the library came from and how its version was read, or why none is usable (a sentence).
    """

    path: str | None
    major: int | None
    how: str

    @property
    def usable(self) -> bool:
        return self.path is not None


def _elf_dynamic(path: str) -> tuple[str | None, bytes]:
    """``(DT_SONAME, the dynamic string table)`` of ELF shared object ``path``; ``(None, b"")`` if it is not one
    or cannot be read."""
    try:
        with open(path, "rb") as f:
            ident = f.read(16)
            if ident[:4] != b"\x7fELF":
                return None, b""
            is64, end = ident[4] == 2, "<" if ident[5] == 1 else ">"
            f.seek(0)
            hdr = f.read(64 if is64 else 52)
            shoff, = struct.unpack_from(end + ("Q" if is64 else "I"), hdr, 0x28 if is64 else 0x20)
            shentsize, shnum, _ = struct.unpack_from(end + "HHH", hdr, 0x3A if is64 else 0x2E)
            f.seek(shoff)
            table = f.read(shentsize * shnum)
            entry = end + ("IIQQQQI" if is64 else "IIIIIII")
            sections = [struct.unpack_from(entry, table, i * shentsize)[1:7] for i in range(shnum)]
            dynamic = next((s for s in sections if s[0] == _SHT_DYNAMIC), None)
            if dynamic is None:
                return None, b""
            _, _, _, str_off, str_size, _ = sections[dynamic[5]]
            f.seek(str_off)
            strings = f.read(str_size)
            f.seek(dynamic[3])
            raw = f.read(dynamic[4])
    except (OSError, struct.error, IndexError):
        return None, b""
    fmt, step = (end + "qQ", 16) if is64 else (end + "iI", 8)
    for k in range(0, len(raw) - step + 1, step):
        tag, value = struct.unpack_from(fmt, raw, k)
        if tag == _DT_NULL:
            break
        if tag == _DT_SONAME and value < len(strings):
            return strings[value:strings.find(b"\x00", value)].decode(errors="replace"), strings
    return None, strings


def _major_from_name(name: str) -> int | None:
    for pattern in _NAME_RES:
        match = pattern.match(os.path.basename(name))
        if match:
            return int(match.group(1))
    return None


def llvm_major(path: str) -> tuple[int | None, str]:
    """The LLVM major version of library ``path`` (symlinks followed) and where it was read, without loading it.

    Returns:
        ``(major, "soname libLLVM.so.19.1")`` and the like; ``(None, reason)`` when no version can be read.
    """
    real = os.path.realpath(path)
    soname, strings = _elf_dynamic(real)
    if soname and _major_from_name(soname) is not None:
        return _major_from_name(soname), f"soname {soname}"
    majors = {int(m) for m in _VERSION_DEF.findall(strings)}
    if len(majors) == 1:
        major = majors.pop()
        return major, f"symbol versions LLVM_{major}"
    for name in (path, real):
        if _major_from_name(name) is not None:
            return _major_from_name(name), f"file name {os.path.basename(name)}"
    return None, "no LLVM version in its soname, symbol versions or file name"


def _candidates(dirs: tuple[str, ...]) -> list[str]:
    """``libLLVM-*.so*`` / ``libLLVM.so*`` files in ``dirs`` (globs), one path per distinct real file."""
    seen: set[str] = set()
    out = []
    for pattern in dirs:
        for folder in sorted(glob.glob(pattern)):
            for path in sorted(glob.glob(os.path.join(folder, "libLLVM*.so*"))):
                base = os.path.basename(path)
                real = os.path.realpath(path)
                if not base.startswith(("libLLVM-", "libLLVM.so")) or real in seen or not os.path.isfile(real):
                    continue  # libLLVMCore.a and the like; a second link to a file already seen
                seen.add(real)
                out.append(path)
    return out


def _check_given(path: str) -> LibLLVM:
    """``DRJIT_LIBLLVM_PATH``'s library, or why it cannot be used."""
    if not os.path.exists(path):
        return LibLLVM(None, None, f"{ENV}={path!r} does not exist")
    if os.path.isdir(path):
        return LibLLVM(None, None, f"{ENV}={path!r} is a folder; it must name the libLLVM*.so file")
    major, how = llvm_major(path)
    if major is None:
        return LibLLVM(None, None, f"{ENV}={path!r}: {how}")
    if major < MIN_MAJOR:
        return LibLLVM(None, major, f"{ENV}={path!r} is LLVM {major} ({how}); Mitsuba's LLVM variant needs "
                                    f"LLVM >= {MIN_MAJOR} (older ones abort the process at the first render)")
    return LibLLVM(path, major, f"{ENV} (LLVM {major}, {how})")


def find_libllvm(environ: dict[str, str] | None = None, dirs: tuple[str, ...] = SEARCH_DIRS) -> LibLLVM:
    """The libLLVM Mitsuba's LLVM variant should load: ``DRJIT_LIBLLVM_PATH`` if set in ``environ`` (default
    ``os.environ``), checked; else the newest major >= :data:`MIN_MAJOR` in ``dirs`` (shortest path among
    equals). Nothing is loaded. ``LibLLVM.path is None`` when none is usable, with the reason in ``how``."""
    env = (os.environ if environ is None else environ).get(ENV)
    if env:
        return _check_given(env)
    found = []
    for path in _candidates(dirs):
        major, how = llvm_major(path)
        if major is not None:
            found.append((major, len(path), path, how))
    found.sort(key=lambda t: (-t[0], t[1]))
    if not found or found[0][0] < MIN_MAJOR:
        seen = ", ".join(f"{p} (LLVM {m})" for m, _, p, _ in found) or "none"
        return LibLLVM(None, found[0][0] if found else None,
                       f"no libLLVM >= {MIN_MAJOR} in {', '.join(dirs)} (found: {seen})")
    major, _, path, how = found[0]
    return LibLLVM(os.path.realpath(path), major, f"found in the library folders (LLVM {major}, {how})")


def point_drjit_at(lib: LibLLVM) -> bool:
    """Make Dr.Jit load ``lib``: set ``DRJIT_LIBLLVM_PATH`` to it, which only takes effect before ``drjit`` is
    imported. Returns whether Dr.Jit will use (or already uses) ``lib``: ``False`` when ``lib`` is unusable or
    ``drjit`` was imported before with another (or no) ``DRJIT_LIBLLVM_PATH``."""
    if not lib.usable:
        return False
    if "drjit" in sys.modules:
        return os.environ.get(ENV) == lib.path
    os.environ[ENV] = str(lib.path)
    return True


# --- the path tracer's variant -----------------------------------------------------------------------------
#: ``render.pbr_variant`` values and the Mitsuba variant each names (``auto``: the first of them that works).
PBR_VARIANTS = {"auto": "", "cuda": "cuda_ad_rgb", "llvm": "llvm_ad_rgb", "scalar": "scalar_rgb"}
_log = logging.getLogger("simtest.render.pbr")
#: Set in this process's environment (so spawned workers inherit it) once a fallback has been logged.
_NOTED_ENV = "SIMTEST_PBR_VARIANT_NOTED"


@dataclass(frozen=True)
class Variant:
    """The Mitsuba variant a ``render.pbr_variant`` request resolved to.

    Attributes:
        name: Mitsuba variant (``cuda_ad_rgb``, ``llvm_ad_rgb`` or ``scalar_rgb``).
        libllvm: On ``llvm_ad_rgb``, the libLLVM file Dr.Jit loaded; else ``None``.
        libllvm_version: Its full version as Dr.Jit reports it (``"19.1.7"``); else ``None``.
    """

    name: str
    libllvm: str | None = None
    libllvm_version: str | None = None


def _cuda(mi) -> str | None:
    """``None`` when ``cuda_ad_rgb`` can run here, else why not."""
    if "cuda_ad_rgb" not in mi.variants():
        return "this Mitsuba build has no cuda_ad_rgb variant"
    try:
        import drjit

        if drjit.has_backend(drjit.JitBackend.CUDA):
            return None
    except Exception:  # no driver, no device
        pass
    return "no CUDA device answers"


def _llvm(mi) -> tuple[Variant | None, str]:
    """``llvm_ad_rgb`` with its libLLVM when it can run here (the variant is then set), else ``(None, why)``."""
    if "llvm_ad_rgb" not in mi.variants():
        return None, "this Mitsuba build has no llvm_ad_rgb variant"
    lib = find_libllvm()
    if not lib.usable:
        return None, lib.how
    if not point_drjit_at(lib):
        return None, (f"drjit was imported before simtest could set {ENV}={lib.path!r}; set it before starting "
                      f"Python, or import simtest's pbr renderer before mitsuba")
    import drjit

    try:
        mi.set_variant("llvm_ad_rgb")
    except ImportError as exc:  # Dr.Jit could not load or use the library
        return None, f"Dr.Jit's LLVM backend is inactive with {lib.path!r} ({exc})"
    version = ".".join(str(v) for v in drjit.detail.llvm_version())
    return Variant("llvm_ad_rgb", str(lib.path), version), ""


def note_once(level: int, message: str) -> None:
    """Log ``message`` unless this process (or the one that spawned it) already did."""
    noted = os.environ.get(_NOTED_ENV, "")
    key = f"{zlib.crc32(message.encode()):08x}"
    if message in _NOTED or key in noted.split(","):
        return
    _NOTED.add(message)
    os.environ[_NOTED_ENV] = ",".join(filter(None, (noted, key)))
    _log.log(level, message)


_NOTED: set[str] = set()


def choose_variant(mi, requested: str) -> Variant:
    """The Mitsuba variant for ``render.pbr_variant = requested`` (sets it in ``mi``).

    ``auto``: ``cuda_ad_rgb`` when the wheel has it and a CUDA device answers, else ``llvm_ad_rgb`` when a
    libLLVM >= 16 is found (:func:`find_libllvm`), else ``scalar_rgb``; each fallback is logged once (CUDA's
    absence at info level, LLVM's as a warning naming what to install). An explicit ``cuda`` or ``llvm`` that
    cannot run is an error.

    Raises:
        RenderError: ``requested`` is not a key of :data:`PBR_VARIANTS`, or an explicit variant is unavailable
            (the message says why and what to install).
    """
    from simtest.errors import RenderError

    if requested not in PBR_VARIANTS:
        raise RenderError(f"render.pbr_variant = {requested!r} is invalid; allowed: "
                          f"{' | '.join(map(repr, PBR_VARIANTS))}")
    if requested in ("auto", "cuda"):
        why = _cuda(mi)
        if why is None:
            mi.set_variant("cuda_ad_rgb")
            return Variant("cuda_ad_rgb")
        if requested == "cuda":
            raise RenderError(f"render.pbr_variant = 'cuda' cannot run: {why}; use 'auto', 'llvm' or 'scalar'")
        note_once(logging.INFO, f"pbr: {why}; path tracing on the CPU")
    if requested in ("auto", "llvm"):
        chosen, why = _llvm(mi)
        if chosen is not None:
            return chosen
        if requested == "llvm":
            raise RenderError(f"render.pbr_variant = 'llvm' cannot run: {why}; {INSTALL_LLVM} (or use 'auto' "
                              f"or 'scalar')")
        note_once(logging.WARNING, f"pbr: path tracing on Mitsuba's scalar_rgb variant, about 3x slower than "
                                    f"llvm_ad_rgb: {why}; to use it, {INSTALL_LLVM}")
    if "scalar_rgb" not in mi.variants():
        raise RenderError(f"this Mitsuba build has no 'scalar_rgb' variant (it has {mi.variants()}); reinstall "
                          f"with: pip install 'simtest[pbr]'")
    mi.set_variant("scalar_rgb")
    return Variant("scalar_rgb")


def without_gc(fn, *args):
    """``fn(*args)`` with Python's cyclic garbage collector paused. A Dr.Jit frozen function must not free an
    array that wraps numpy memory while it records (Dr.Jit's LLVM backend releases such memory through a host
    callback, which a recording refuses by terminating the process); a collection that starts inside a recording
    can free exactly that: an earlier scene's meshes, whose buffers come from numpy, held in a reference cycle."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        return fn(*args)
    finally:
        if enabled:
            gc.enable()
