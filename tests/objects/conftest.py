"""Fixtures for the object tests: the built-in sets (built once per session, cached in-process)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def builtin():
    from simtest.objects import load_object_set

    return load_object_set("builtin")


@pytest.fixture(scope="session")
def builtin_small():
    from simtest.objects import load_object_set

    return load_object_set("builtin-small")

