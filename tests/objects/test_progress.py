"""The progress of an object set's first use: a bar naming the object being worked on, shown only when the work
is slow, and a closing line naming the slowest object (``simtest.objects.progress``, ``prepare_set``, ``simtest
objects list``)."""

from __future__ import annotations

import io
import logging
import re
import time

import pytest

from simtest.cli import main
from simtest.objects import load_object_set, progress
from simtest.objects.prepare import prepare_set
from simtest.objects.progress import ObjectProgress, progress_enabled


def _run(work: dict[str, float], **kwargs) -> tuple[ObjectProgress, str]:
    """Steps that sleep the given seconds, under a bar drawn into a string."""
    out = io.StringIO()
    with ObjectProgress(len(work), "test work", file=out, **kwargs) as bar:
        for name, seconds in work.items():
            with bar.step(name):
                time.sleep(seconds)
    return bar, out.getvalue()


def test_fast_work_draws_nothing_slow_work_names_objects_and_the_slowest():
    bar, text = _run({"a": 0.0, "b": 0.0}, progress=True)
    assert text == "" and not bar.shown and [n for n, _ in bar.times] == ["a", "b"]
    bar, text = _run({"quick": 0.01, "slowpoke": 0.3, "last": 0.01}, progress=True, show_after=0.0,
                     summary_after=0.0)
    assert bar.shown
    assert "test work: quick" in text and "test work: slowpoke" in text and "test work: last" in text
    assert "3/3" in text
    assert re.search(r"simtest: test work of 3 objects took \d+\.\d s; slowest: slowpoke \(0\.\d s\)\n$", text)
    # Shown, but over before summary_after: the bar is erased at the end and no closing line is written.
    bar, text = _run({"a": 0.01}, progress=True, show_after=0.0, summary_after=60.0)
    assert bar.shown and "slowest" not in text and text.endswith("\r")
    # Off: nothing drawn, the times are still kept.
    bar, text = _run({"a": 0.05}, progress=False, show_after=0.0, summary_after=0.0)
    assert text == "" and len(bar.times) == 1


def test_a_step_known_to_compute_shows_the_bar_at_once():
    out = io.StringIO()
    with ObjectProgress(2, "work", True, show_after=60.0, file=out) as bar:
        with bar.step("cached"):
            pass
        assert not bar.shown
        with bar.step("decomposed"):
            bar.computing()
            assert bar.shown and "work: decomposed" in out.getvalue()


def test_an_error_leaves_the_bar_at_the_object_it_stopped_at():
    out = io.StringIO()
    with pytest.raises(ValueError):
        with ObjectProgress(3, "work", True, show_after=0.0, summary_after=0.0, file=out) as bar:
            with bar.step("fine"):
                pass
            with bar.step("broken"):
                raise ValueError("unreadable mesh")
    assert [n for n, _ in bar.times] == ["fine"]
    text = out.getvalue()
    assert "work: broken" in text and "1/3" in text and text.endswith("\n") and "slowest" not in text


def test_default_follows_quiet_logging(monkeypatch):
    logger = logging.getLogger("simtest")
    monkeypatch.setattr(logger, "level", logging.ERROR)  # what --quiet sets
    assert progress_enabled(None) is False and progress_enabled(True) is True
    monkeypatch.setattr(logger, "level", logging.WARNING)
    assert progress_enabled(None) is True and progress_enabled(False) is False


def test_prepare_set_reports_computed_then_cached(mesh_folder):
    objects = load_object_set(str(mesh_folder), units="m")
    first = {r.name: r for r in prepare_set(objects, progress=False)}
    assert first["banana"].collision == "computed" and first["banana"].parts >= 2
    assert first["box"].collision == "hull" and first["box"].parts == 1
    again = load_object_set(str(mesh_folder), units="m")
    second = prepare_set(again, [again.by_name("banana").obj_id], grasps=True, progress=False)
    assert [(r.name, r.collision, r.parts) for r in second] == [("banana", "cached", first["banana"].parts)]
    assert "grasps" in again.by_name("banana").__dict__  # sampled and kept on the object
    with pytest.raises(Exception, match="unknown object id 99"):
        prepare_set(again, [99], progress=False)


def test_objects_list_first_use_shows_bar_naming_objects_and_slowest(mesh_folder, tmp_path, monkeypatch, capsys):
    args = ["objects", "list", "--set", str(mesh_folder), "--units", "m"]
    assert main(args + ["--quiet"]) == 0  # --quiet: no bar, no closing line, even on first use
    assert capsys.readouterr().err == ""
    monkeypatch.setenv("SIMTEST_CACHE", str(tmp_path / "fresh"))  # first use again, drawn this time
    monkeypatch.setattr(progress, "SUMMARY_MIN_S", 0.0)  # the closing line without 10 s of work
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "banana" in captured.out and "box" in captured.out  # the table
    err = captured.err
    assert "collision parts + grasps: banana" in err  # shown at once: its decomposition is computed
    assert "collision parts + grasps: box" in err and "2/2" in err
    assert re.search(r"simtest: collision parts \+ grasps of 2 objects took \d+\.\d s; "
                     r"slowest: (banana|box) \(\d+\.\d s\)", err)
    # Cached afterwards: no bar (the table is made in well under the time that would show one).
    monkeypatch.setattr(progress, "SUMMARY_MIN_S", 10.0)
    monkeypatch.setattr(progress, "SHOW_AFTER_S", 30.0)
    assert main(args) == 0
    assert "collision parts" not in capsys.readouterr().err


def test_symmetry_detection_of_a_set_shows_a_bar_naming_each_object(mesh_folder, monkeypatch, capsys):
    monkeypatch.setattr(logging.getLogger("simtest"), "level", logging.WARNING)  # not --quiet
    monkeypatch.setattr(progress, "SHOW_AFTER_S", 0.0)
    monkeypatch.setattr(progress, "SUMMARY_MIN_S", 0.0)
    objects = load_object_set(str(mesh_folder), units="m")
    assert {o.extra["symmetry"] for o in objects} == {"detected"}
    err = capsys.readouterr().err
    assert "symmetries: banana" in err and "symmetries: box" in err and "2/2" in err
    assert re.search(r"simtest: symmetries of 2 objects took \d+\.\d s; slowest: (banana|box) \(\d+\.\d s\)", err)


def test_a_scale_change_says_which_key_field_forced_the_recomputation(mesh_folder, caplog, monkeypatch):
    from simtest.objects import symmetry_detect

    monkeypatch.setattr(symmetry_detect, "_CACHE", {})  # symmetries of these meshes found by earlier tests
    with caplog.at_level(logging.WARNING, logger="simtest"):
        prepare_set(load_object_set(str(mesh_folder), units="m"), progress=False)
        assert not [r for r in caplog.records if "again" in r.getMessage()]  # a first computation says nothing
        prepare_set(load_object_set(str(mesh_folder), units="m"), progress=False)  # cached: nothing to say
        assert not [r for r in caplog.records if "again" in r.getMessage()]
        prepare_set(load_object_set(str(mesh_folder), units="m", scale=0.5), progress=False)
    lines = [r.getMessage() for r in caplog.records if "again" in r.getMessage()]
    banana = str(mesh_folder / "banana.obj")
    assert f"{banana}: collision parts computed again: the cache key changed (scale 1 -> 0.5)" in lines
    assert f"{banana}: symmetries detected again: the cache key changed (scale 1 -> 0.5)" in lines
    assert len(lines) == 3  # the box: its symmetries (a convex box has no decomposition)


def test_key_changes_name_the_field():
    from simtest.objects.cache import describe_key_change

    before = {"units": "m", "scale": 1.0, "version": 2, "mesh": "a" * 40}
    assert describe_key_change(before, dict(before)) is None
    assert describe_key_change(before, {**before, "scale": 0.01, "mesh": "b" * 40}) == "scale 1 -> 0.01"
    assert describe_key_change(before, {**before, "mesh": "b" * 40}) == f"mesh {'a' * 12} -> {'b' * 12}"
    assert describe_key_change(before, {**before, "version": 3, "units": "cm"}) == "units m -> cm, version 2 -> 3"
