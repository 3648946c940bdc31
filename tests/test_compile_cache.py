"""The compiled functions' disk cache (``analysis/compile.py``): an entry keyed by the function's
structure, so that a hit generates no C; one lock per entry, so that processes needing the same
library build it once; another structure, another entry."""

from __future__ import annotations

import multiprocessing
import os

import casadi as cs
import numpy as np
import pytest

from dvfc.analysis import compile as compile_module
from dvfc.analysis.compile import compiled


def square(name: str = "dvfc_square", power: float = 2.0) -> cs.Function:
    x = cs.SX.sym("x", 3)
    return cs.Function(name, [x], [x**power])


@pytest.fixture
def cold(tmp_path, monkeypatch):
    """A fresh cache directory and no function loaded in this process."""
    monkeypatch.setenv("DVFC_CACHE", str(tmp_path))
    monkeypatch.setattr(compile_module, "_loaded", {})
    return tmp_path


def test_a_cache_hit_generates_no_c_source(cold, monkeypatch):
    """Built once; in a process that has not loaded it (the in-process table emptied), the same
    function is loaded from the cache without generating its C (generating it here fails the test)."""
    first = compiled(square())
    assert len(list(cold.glob("dvfc_square-*.so"))) == 1
    monkeypatch.setattr(compile_module, "_loaded", {})
    monkeypatch.setattr(compile_module, "_source", lambda *a: pytest.fail("C generated on a cache hit"))
    again = compiled(square())
    assert np.array_equal(np.asarray(again([1.0, 2.0, 3.0])), np.asarray(first([1.0, 2.0, 3.0])))


def test_another_structure_or_build_is_another_entry(cold):
    """A different expression or another optimisation level: each its own library, each computing its own
    function; the same function loaded differentiable is the same library."""
    compiled(square())
    cube = compiled(square(power=3.0))
    compiled(square(), level="-O2")
    compiled(square(), differentiable=True)
    assert len(list(cold.glob("dvfc_square-*.so"))) == 3
    assert np.allclose(np.asarray(cube([1.0, 2.0, 3.0])).ravel(), [1.0, 8.0, 27.0])


def test_a_differentiable_library_has_the_symbolic_jacobian_to_differences_accuracy(cold):
    """Loaded differentiable, a compiled function's Jacobian (forward differences at CasADi's step) equals the
    symbolic one to 1e-6 of its largest entry: measured 2.2e-8, about ``sqrt(eps)`` (truncation ``h f''`` and
    round-off ``eps / h`` at ``h`` near ``sqrt(eps)``); a step of 0.01 leaves 1.5e-2. Loaded without, it has no
    derivative."""
    x = cs.SX.sym("x", 3)
    expression = cs.vertcat(cs.exp(3.0 * x[0]) * cs.sin(x[1]), x[1] ** 3 / (1.0 + x[2] ** 2), cs.tanh(x[0] / 0.05))
    function = cs.Function("dvfc_curved", [x], [expression])
    at = np.array([0.3, -0.7, 1.2])
    exact = np.asarray(cs.Function("j", [x], [cs.jacobian(expression, x)])(at))
    differenced = compiled(function, differentiable=True).jacobian()(at, 0)
    assert np.allclose(np.asarray(differenced), exact, rtol=0.0, atol=1e-6 * np.abs(exact).max())
    with pytest.raises(RuntimeError):
        compiled(function).jacobian()(at, 0)


def _build_in_child(cache: str, marks: str, barrier) -> None:
    """In a child process: compile ``square`` into ``cache``, leaving a file in ``marks`` when this
    process generated the C (it built the library)."""
    import os
    from pathlib import Path

    os.environ["DVFC_CACHE"] = cache
    compile_module._loaded.clear()
    generate = compile_module._source

    def marked(*args):
        Path(marks, str(os.getpid())).touch()
        return generate(*args)

    compile_module._source = marked
    barrier.wait()
    compiled(square())


def test_processes_needing_one_library_at_once_build_it_once(cold, tmp_path_factory):
    """Three processes released together ask for the same library of a fresh cache: one builds it,
    the others wait on the entry's lock and load it; no partial file is left."""
    marks = tmp_path_factory.mktemp("marks")
    context = multiprocessing.get_context("fork")
    barrier = context.Barrier(3)
    children = [context.Process(target=_build_in_child, args=(str(cold), str(marks), barrier)) for _ in range(3)]
    for child in children:
        child.start()
    for child in children:
        child.join(60)
    assert [child.exitcode for child in children] == [0, 0, 0]
    assert len(list(marks.iterdir())) == 1
    assert len(list(cold.glob("dvfc_square-*.so"))) == 1 and not list(cold.glob("*.tmp"))


def _recording_compiler(log):
    """A compiler that records when it starts (``start.<pid>``) and its niceness (``nice.<pid>``), sleeps 1 s,
    runs the real one and records when it ends (``end.<pid>``)."""
    import shutil

    wrapper = log / "cc"
    real = shutil.which("gcc") or shutil.which("cc")
    wrapper.write_text(f'#!/bin/sh\n[ "$1" = --version ] && exec {real} --version\ndate +%s.%N > "{log}/start.$$"\n'
                       f'nice > "{log}/nice.$$"\nsleep 1\n{real} "$@"\nstatus=$?\ndate +%s.%N > "{log}/end.$$"\n'
                       'exit $status\n')  # fmt: skip
    wrapper.chmod(0o755)
    return wrapper


def test_the_libraries_of_one_batch_are_built_at_once(cold, monkeypatch, tmp_path_factory):
    """:func:`compiled_together` with two functions not in the cache: each built once, each computing its own
    function, their compilers running at the same time on a machine with two cores or more (a compiler that
    records when it starts, sleeps 1 s, runs the real one and records when it ends: the two intervals overlap)."""
    import time

    from dvfc.analysis.compile import compiled_together

    log = tmp_path_factory.mktemp("log")
    wrapper = _recording_compiler(log)
    monkeypatch.setattr(compile_module.shutil, "which", lambda name: str(wrapper))
    started = time.perf_counter()
    square_, cube = compiled_together([(square(), False, "-O1"), (square(power=3.0), False, "-O1")])
    assert len(list(cold.glob("dvfc_square-*.so"))) == 2
    assert np.allclose(np.asarray(cube([1.0, 2.0, 3.0])).ravel(), [1.0, 8.0, 27.0])
    assert np.allclose(np.asarray(square_([1.0, 2.0, 3.0])).ravel(), [1.0, 4.0, 9.0])
    runs = [(float((log / f"start.{pid}").read_text()), float((log / f"end.{pid}").read_text()))
            for pid in sorted(p.name.split(".")[1] for p in log.glob("start.*"))]  # fmt: skip
    assert len(runs) == 2 and time.perf_counter() - started > 1.0
    if (os.cpu_count() or 1) >= 2:
        (a_start, a_end), (b_start, b_end) = runs
        assert a_start < b_end and b_start < a_end


def test_a_build_started_ahead_runs_at_the_lowest_priority_and_is_waited_for_not_repeated(
    cold, monkeypatch, tmp_path_factory
):
    """Within :func:`ahead`, ``compiled_together`` returns at once (before the 1 s compiler ends) with the
    function as it is, its build started at nice 19; the later ``compiled_together`` of the same function waits
    for that build (no C generated again, one compiler run) and loads the library; a build it starts itself
    runs at the process's own priority."""
    import time

    from dvfc.analysis.compile import ahead, compiled_together

    log = tmp_path_factory.mktemp("log")
    wrapper = _recording_compiler(log)
    monkeypatch.setattr(compile_module.shutil, "which", lambda name: str(wrapper))
    started = time.perf_counter()
    with ahead():
        (early,) = compiled_together([(square(), False, "-O1")])
    assert time.perf_counter() - started < 0.9 and early.class_name() == "SXFunction"
    generate = compile_module._source
    monkeypatch.setattr(compile_module, "_source", lambda *a: pytest.fail("C generated again"))
    (late,) = compiled_together([(square(), False, "-O1")])
    assert late.class_name() == "External" and np.allclose(np.asarray(late([1.0, 2.0, 3.0])).ravel(), [1.0, 4.0, 9.0])
    assert [int(p.read_text()) for p in log.glob("nice.*")] == [19] and len(list(log.glob("end.*"))) == 1
    monkeypatch.setattr(compile_module, "_source", generate)
    for mark in log.glob("nice.*"):
        mark.unlink()
    compiled_together([(square(power=3.0), False, "-O1")])
    assert [int(p.read_text()) for p in log.glob("nice.*")] == [os.nice(0)]


def test_a_child_forked_while_a_build_runs_ahead_waits_for_its_library_and_loads_it(
    cold, monkeypatch, tmp_path_factory
):
    """A process forked while its parent builds a library ahead (the parent's compiler threads are not the
    child's) asks for that library: it waits on the entry's lock, then loads it (generating no C), within 20 s,
    built once."""
    from dvfc.analysis.compile import ahead, compiled_together

    log = tmp_path_factory.mktemp("log")
    wrapper = _recording_compiler(log)
    monkeypatch.setattr(compile_module.shutil, "which", lambda name: str(wrapper))
    with ahead():
        compiled_together([(square(), False, "-O1")])
    marks = tmp_path_factory.mktemp("marks")
    context = multiprocessing.get_context("fork")
    child = context.Process(target=_build_in_child, args=(str(cold), str(marks), context.Barrier(1)))
    child.start()
    child.join(20)
    if child.is_alive():
        child.kill()
    assert child.exitcode == 0 and not list(marks.iterdir())
    compiled(square())
    assert len(list(log.glob("end.*"))) == 1
