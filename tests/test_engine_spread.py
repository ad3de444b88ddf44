"""run_tasks: order, sinks, errors with their items, the pool's retries, pinned threads."""
from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
import subprocess
import sys

import numpy as np
import pytest
from tactile_mirror.engine import TaskError, open_executor, pinned_threads, run_tasks, warm_workers


def square(x):
    return x * x


def fail_on_three(x):
    if x == 3:
        raise ValueError("three is bad")
    return x


def blas_threads(_):
    from threadpoolctl import threadpool_info

    return sorted({p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"}), \
        os.environ.get("OMP_NUM_THREADS")


def die_once(args):
    """Kills its worker process the first time (marker file absent), then answers."""
    x, marker = args
    if x == 2 and not os.path.exists(marker):
        open(marker, "w").close()
        os._exit(3)
    return x


@pytest.fixture(scope="module")
def pool():
    with open_executor(workers=2) as ex:
        yield ex


@pytest.mark.parametrize("where", ["serial", "threads", "processes"])
def test_results_come_in_item_order_wherever_they_run(where, pool):
    items = list(range(12))[::-1]
    if where == "serial":
        out = run_tasks(square, items, progress=False)
    elif where == "threads":
        with concurrent.futures.ThreadPoolExecutor(3) as ex:
            out = run_tasks(square, items, executor=ex, progress=False)
    else:
        out = run_tasks(square, items, executor=pool, progress=False)
    assert list(out) == [x * x for x in items]
    assert out.failures == []


def test_ordered_sink_sees_every_result_in_item_order_and_keep_false_holds_none(pool):
    seen = []
    out = run_tasks(square, range(10), executor=pool, sink=lambda k, v: seen.append((k, v)), ordered=True,
                    keep=False, progress=False)
    assert seen == [(k, k * k) for k in range(10)]
    assert list(out) == [None] * 10


def test_first_error_names_its_item_and_keeps_the_cause():
    with pytest.raises(TaskError, match=r"task 3 failed on item 3: ValueError: three is bad") as info:
        run_tasks(fail_on_three, range(6), progress=False)
    assert isinstance(info.value.__cause__, ValueError)
    assert (info.value.index, info.value.item) == (3, 3)


def test_continue_lists_the_failures_at_the_end(pool):
    with pytest.warns(RuntimeWarning, match=r"1 of 6 tasks failed:\n  task 3 \(3\): ValueError"):
        out = run_tasks(fail_on_three, range(6), executor=pool, on_error="continue", progress=False)
    assert list(out) == [0, 1, 2, None, 4, 5]
    assert [(f.index, f.item) for f in out.failures] == [(3, 3)]


def test_own_pool_restarts_when_a_worker_dies(tmp_path):
    marker = str(tmp_path / "died")
    with pytest.warns(RuntimeWarning, match="a worker process died; restarting the pool"):
        out = run_tasks(die_once, [(x, marker) for x in range(5)], workers=2, progress=False)
    assert list(out) == list(range(5))


def test_an_outside_pool_broken_by_a_lost_worker_names_the_first_unfinished_item(tmp_path):
    import multiprocessing

    marker = str(tmp_path / "died")
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as ex:
        with pytest.raises(TaskError, match=r"task \d failed on item \(\d, .*BrokenProcessPool") as info:
            run_tasks(die_once, [(x, marker) for x in range(4)], executor=ex, progress=False)
    assert info.value.index >= 2  # items 0 and 1 were done before the worker died


def test_tasks_run_with_pinned_threads_whatever_the_parent_has(monkeypatch):
    from threadpoolctl import threadpool_limits

    # the parent at 2 threads, in its pools and in the variables its workers start with
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.setenv(name, "2")
    outside = concurrent.futures.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
    with outside, threadpool_limits(limits=2), concurrent.futures.ThreadPoolExecutor(2) as threads:
        assert outside.submit(blas_threads, 0).result()[1] == "2"  # unpinned, the worker has the parent's
        serial = run_tasks(blas_threads, [0], progress=False, threads=1)[0]
        in_threads = run_tasks(blas_threads, [0, 1], executor=threads, progress=False, threads=1)
        remote = run_tasks(blas_threads, [0], executor=outside, progress=False, threads=1)[0]
    assert serial == remote == in_threads[0] == in_threads[1]
    assert serial[1] == "1" and serial[0] in ([1], [])  # [] where numpy has no BLAS pool to report


def test_a_task_failing_on_a_thread_pool_names_its_item_in_a_fresh_process():
    # (a fresh interpreter: no other module has loaded concurrent.futures.process)
    code = ("import concurrent.futures as cf\n"
            "from tactile_mirror.engine import TaskError, run_tasks\n"
            "def bad(x):\n"
            "    if x == 1: raise KeyError(x)\n"
            "    return x\n"
            "try:\n"
            "    with cf.ThreadPoolExecutor(2) as ex: run_tasks(bad, range(3), executor=ex, progress=False)\n"
            "except TaskError as e: print('TaskError', e.index)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "TaskError 1", out.stderr


def test_pinned_threads_restores_the_parent_and_refuses_a_second_count():
    before = os.environ.get("OMP_NUM_THREADS")
    with pinned_threads(1):
        assert os.environ["OMP_NUM_THREADS"] == "1"
        with pinned_threads(1):
            pass
        with pytest.raises(ValueError, match="already pinned to 1"):
            with pinned_threads(2):
                pass
        assert os.environ["OMP_NUM_THREADS"] == "1"
    assert os.environ.get("OMP_NUM_THREADS") == before


@pytest.mark.parametrize("kwargs, match", [
    ({"on_error": "skip"}, "on_error must be one of"),
    ({"threads": 0}, "threads must be a positive integer"),
    ({"workers": 0}, "workers must be a positive integer or None"),
    ({"retries": -1}, "retries must be a non-negative integer"),
    ({"executor": object()}, "executor must be a concurrent.futures.Executor"),
    ({"sink": 3}, "sink must be callable"),
])
def test_bad_options_are_named(kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        run_tasks(square, [1], progress=False, **kwargs)


def test_a_failing_task_of_a_numpy_sweep_reports_its_array_briefly():
    with pytest.raises(TaskError, match=r"item array\(\[") as info:
        run_tasks(np.linalg.inv, [np.eye(2), np.zeros((2, 2))], progress=False)
    assert info.value.index == 1


@pytest.mark.parametrize("chunk", [1, 3, 4, 100])
def test_chunks_keep_each_items_result_error_and_sink_call(chunk, pool):
    seen = []
    with pytest.warns(RuntimeWarning, match=r"1 of 10 tasks failed:\n  task 3 \(3\): ValueError"):
        out = run_tasks(fail_on_three, range(10), executor=pool, chunk=chunk, sink=lambda k, v: seen.append((k, v)),
                        ordered=True, on_error="continue", progress=False)
    assert list(out) == [0, 1, 2, None, 4, 5, 6, 7, 8, 9]
    assert seen == [(k, k) for k in range(10) if k != 3]
    with pytest.raises(TaskError, match="task 3 failed on item 3"):
        run_tasks(fail_on_three, range(10), workers=2, chunk=chunk, progress=False)
    with pytest.raises(ValueError, match="chunk must be a positive integer or .auto."):
        run_tasks(square, [1], chunk=0, progress=False)


class RecordingExecutor(concurrent.futures.ThreadPoolExecutor):
    """A thread pool that records the items in the order their tasks were submitted."""

    def __init__(self):
        super().__init__(1)
        self.submitted = []

    def submit(self, fn, /, *args, **kwargs):
        self.submitted.append(args[1])
        return super().submit(fn, *args, **kwargs)


def test_order_sets_the_submission_order_and_nothing_else(tmp_path):
    seen = []
    with RecordingExecutor() as ex:
        out = run_tasks(square, [1, 2, 3, 4], executor=ex, order=[3, 1, 0, 2], sink=lambda k, v: seen.append(k),
                        ordered=True, progress=False)
    assert ex.submitted == [4, 2, 1, 3]
    assert list(out) == [1, 4, 9, 16] and seen == [0, 1, 2, 3]
    for bad in ([0, 1, 2], [0, 0, 1, 2], [1, 2, 3, 4]):
        with pytest.raises(ValueError, match="order must be a permutation of the 4 item indices"):
            run_tasks(square, [1, 2, 3, 4], order=bad, progress=False)
    with pytest.raises(ValueError, match="order and chunk > 1 do not go together"):
        run_tasks(square, [1, 2, 3, 4], order=[0, 1, 2, 3], chunk=2, progress=False)


def test_warm_workers_submits_one_call_per_worker_with_pinned_threads(pool):
    futures = warm_workers(pool, blas_threads, 0)
    assert len(futures) == 2
    assert all(f.result()[1] == "1" for f in futures)
    assert warm_workers(None, blas_threads, 0) == []
