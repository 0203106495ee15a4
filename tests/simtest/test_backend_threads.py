"""The worker thread budget belongs to the back end: one call per worker, and the old place still forwards."""

from __future__ import annotations

import warnings

import pytest

from simtest.backend.threads import available_cores, thread_budget, worker_threads, workers_per_machine


def test_worker_threads_is_the_budget_of_the_workers_on_one_machine():
    assert worker_threads(2) == thread_budget(2)
    assert worker_threads(1) == thread_budget(1)
    # a joined Ray cluster runs one unit per core of the node, whatever `workers` says
    assert worker_threads(7, "auto") == thread_budget(available_cores())
    assert workers_per_machine(3) == 3 and workers_per_machine(3, "10.0.0.1:6379") == available_cores()


def test_the_render_gl_names_forward_to_the_back_end_with_a_deprecation_warning():
    import simtest.backend.threads as threads
    import simtest.render.gl as gl

    for name in gl.MOVED:
        with pytest.warns(DeprecationWarning, match=f"simtest.backend.threads.{name}"):
            assert getattr(gl, name) is getattr(threads, name)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(AttributeError, match="no_such_name"):
            gl.no_such_name  # noqa: B018


def test_gl_does_not_know_about_ray():
    import inspect

    import simtest.render.gl as gl

    assert "ray" not in inspect.getsource(gl).lower().replace("array", "")


def test_blas_threads_holds_numpys_blas_to_the_share_and_gives_it_back():
    import numpy as np
    from threadpoolctl import threadpool_info

    from simtest.backend.threads import blas_threads

    def blas() -> list[int]:
        return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]

    a = np.ones((64, 64), np.float32)
    a @ a  # numpy's BLAS is loaded
    before = blas()
    assert before, "numpy's BLAS is not visible to threadpoolctl"
    with blas_threads(1):
        assert blas() == [1] * len(before)
        assert float((a @ a)[0, 0]) == 64.0
    assert blas() == before
    with pytest.raises(ValueError, match="threads must be at least 1, got 0"):
        blas_threads(0)
