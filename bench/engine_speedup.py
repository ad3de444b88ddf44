"""What spreading buys: two big jobs serially and on a dask LocalCluster, side by side in one run.

    python bench/engine_speedup.py                  # the envelope and the build's simulation, 2 workers
    python bench/engine_speedup.py --workers 4 --scale 8
    python bench/engine_speedup.py --quick          # a smoke run (two short paths, 8 scenes)

The jobs, each run in this process and then on a fresh ``LocalCluster`` of ``--workers``
worker processes (one thread each), its start-up and shut-down inside the time measured:

- the envelope (``run_envelope``): the nominal condition, 4 speed classes x 5 report paths,
  the three default laws (60 runs of 3 s on the FEM pad); its results files are compared
  byte for byte;
- the detector build's scene simulation (``scene_cache.simulate_scenes`` of the build's
  ``random_scenes``, what ``simulate_cached`` runs): its training, held-out and validation sets at
  ``--scale`` times their size (4: 1536 scenes, about 0.045 s each: a serial run of about 70 s);
  the arrays are compared.

Printed: the CPU model and core count, the load average before and after, each job's
times, the cluster's start-up, the speed-up (the issue's goal: at least 1.7x on 2 workers),
and the CPU seconds this process spent in the serial run (about its wall time: it ran
here, not on a pool). Run it on an otherwise idle machine. ``main`` returns how many of the
two jobs gave the serial run's bits on the cluster (2).
"""
from __future__ import annotations

import argparse
import concurrent.futures
import contextlib
import hashlib
import os
import tempfile
import time

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from tactile_mirror.lab.measure import cpu_model  # (after the thread settings)

#: The envelope of the measurement: one condition, 4 classes x 5 paths, the default laws.
ENVELOPE = {"speeds": (0.002, 0.005, 0.01, 0.02), "n_seeds": 5, "duration": 3.0}
#: ``--quick``: one class, one short path, two laws (the design still runs).
QUICK_ENVELOPE = {"speeds": (0.005,), "n_seeds": 2, "duration": 0.8, "laws": ("open loop",)}


@contextlib.contextmanager
def cluster(workers: int):
    """A dask ``LocalCluster`` of ``workers`` processes (one thread each): its client's
    executor and the seconds it took to start (all workers up)."""
    from dask.distributed import Client, LocalCluster

    t0 = time.perf_counter()
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as lc, \
            Client(lc) as client:
        client.wait_for_workers(workers)
        yield client.get_executor(), time.perf_counter() - t0


def timed(job, *args):
    """``job(*args)``'s value, wall seconds and this process's CPU seconds."""
    t0, c0 = time.perf_counter(), time.process_time()
    value = job(*args)
    return value, time.perf_counter() - t0, time.process_time() - c0


def envelope(folder: str, name: str, kwargs: dict, executor=None) -> bytes:
    """The envelope's results file, run on ``executor`` (None: here)."""
    from tactile_mirror.lab.loop.envelope import run_envelope

    path = os.path.join(folder, f"{name}.json")
    run_envelope(path, progress=False, **kwargs, **({} if executor is None else {"executor": executor}))
    with open(path, "rb") as fh:
        return fh.read()


def build_scene_sets(scale: float, quick: bool) -> list[tuple]:
    """The detector build's scene sets (n, seed, scene options): training, held-out and
    validation, at ``scale`` times the build's sizes (``quick``: 4 + 2 + 2 scenes)."""
    from tactile_mirror.lab.detector.build_options import (
        TEST_KWARGS,
        TEST_SEED,
        TRAIN_KWARGS,
        TRAIN_SEED,
        VALIDATION_SEED,
        BuildOptions,
    )

    o = BuildOptions()
    sizes = (4, 2, 2) if quick else tuple(max(1, round(n * scale)) for n in (o.n_train, o.n_test, o.n_validation))
    return [(sizes[0], TRAIN_SEED, TRAIN_KWARGS), (sizes[1], TEST_SEED, TEST_KWARGS),
            (sizes[2], VALIDATION_SEED, TEST_KWARGS)]


class InThisProcess(concurrent.futures.Executor):
    """Runs each task here as it is submitted: the serial run of the scene simulation (which,
    given no executor, starts a pool of this machine's cores), through the same code path."""

    def submit(self, fn, /, *args, **kwargs):
        future = concurrent.futures.Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001  (the future carries it)
            future.set_exception(exc)
        return future


def simulate_sets(sets, executor=None) -> str:
    """The build's simulation of ``sets`` on ``executor`` (None: here, one scene after the
    other), as a digest of every result's arrays (the results themselves are not kept)."""
    import numpy as np
    from tactile_mirror.lab.detector.scene_cache import random_scenes, simulate_scenes

    h = hashlib.sha256()
    for n, seed, kwargs in sets:
        for r in simulate_scenes(random_scenes(n, seed, **kwargs), False, executor=executor or InThisProcess()):
            for name in ("t", "stress", "v_out", "u_out", "slip_fraction", "force_y", "force_z"):
                h.update(np.ascontiguousarray(getattr(r, name)).tobytes())
    return h.hexdigest()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2, help="worker processes of the LocalCluster (default: 2)")
    ap.add_argument("--scale", type=float, default=4.0,
                    help="the build's scene sets at this many times their size (default: 4, 1536 scenes)")
    ap.add_argument("--only", choices=("envelope", "simulation"), default=None, help="one of the two jobs")
    ap.add_argument("--quick", action="store_true", help="two short paths and 8 scenes: a smoke run, not the figures")
    args = ap.parse_args(argv)
    if args.workers < 1 or not args.scale > 0:
        ap.error("--workers and --scale must be positive")

    def load() -> str:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())

    print(f"# engine speed-up: serial against a {args.workers}-worker dask LocalCluster, start-up included")
    print(f"# CPU: {cpu_model()} ({os.cpu_count()} CPUs); load average (1, 5, 15 min) before: {load()}", flush=True)
    sets = build_scene_sets(args.scale, args.quick)
    n_scenes = sum(n for n, _, _ in sets)
    env = QUICK_ENVELOPE if args.quick else ENVELOPE
    runs = len(env["speeds"]) * env["n_seeds"] * len(env.get("laws", (0, 0, 0)))
    speeds = ", ".join(f"{v * 1e3:g}" for v in env["speeds"])
    sizes = "a few of each of the build's sets" if args.quick else f"{args.scale:g}x the build's sets"
    jobs = {"envelope": (f"envelope: nominal, {speeds} mm/s x {env['n_seeds']} paths ({runs} runs of "
                         f"{env['duration']:g} s)"),
            "simulation": f"the build's scene simulation: {n_scenes} scenes ({sizes})"}
    rows, same = [], 0
    with tempfile.TemporaryDirectory() as folder:
        for job, what in jobs.items():
            if args.only not in (None, job):
                continue
            run = (lambda ex=None: envelope(folder, "cluster" if ex else "serial", env, ex)) if job == "envelope" \
                else (lambda ex=None: simulate_sets(sets, ex))
            serial, t_serial, cpu = timed(run)
            t0 = time.perf_counter()
            with cluster(args.workers) as (executor, start):
                spread = run(executor)
            t_cluster = time.perf_counter() - t0  # start-up, run and shut-down
            same += spread == serial
            rows.append((what, t_serial, cpu, start, t_cluster, spread == serial))
            print(f"# {what}: serial {t_serial:.1f} s ({cpu:.1f} s CPU here), cluster {t_cluster:.1f} s "
                  f"(start-up {start:.1f} s); load average now {load()}", flush=True)
    print(f"\n| job | serial s | {args.workers} workers s (start-up s) | speed-up | same bits |\n|---|---|---|---|---|")
    for what, t_serial, cpu, start, t_cluster, ok in rows:
        print(f"| {what} | {t_serial:.1f} | {t_cluster:.1f} ({start:.1f}) | {t_serial / t_cluster:.2f}x | "
              f"{'yes' if ok else 'NO'} |")
    print(f"\n# load average after: {load()}")
    return same


if __name__ == "__main__":
    main()
