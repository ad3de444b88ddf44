"""Benchmarks of the contact simulation.

    python bench/bench_contact.py [--quick] [--solver-only] [--stepping-only] [--realtime-only] [--figures DIR]

Prints markdown tables: the compiled contact solver against the Python reference
(per step, also with the dense kernels compiled for the x86-64 baseline instead of
AVX2+FMA; fig6 end to end, wall and CPU time; the 6-ridge pad step; the paced loop at
1 kHz against the FEM pad), the paper's fig6 scene end to end at 1 kHz, reduced against unreduced solves
of the same steps, cost against the outputs a scene asks for, mesh size against
strip-stress error and run time, and the event-driven stepping ("auto") against the
per-sample one ("every"): time against error on the paper's scenes, the 6-ridge pad and
random scenes, with solves and events, and the stepping's goals; writes Figs. 6-8 and
realtime_pad.png (the pad's contact resolution: tick time against error) as PNG into DIR. The CPU model is
printed first; every ratio is between runs of this one process.

``--quick``: every table from small runs (the paper's scenes on a coarse mesh, h = 0.6 mm, sampled at
250 Hz; short paced runs; coarse meshes against a coarse reference): a smoke run of a few seconds, not
the figures. ``main`` returns the largest strip-stress difference of the compiled event stepping against
the compiled per-sample stepping, relative to the peak ("Event stepping in the compiled solver").
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import tactile_mirror as tm
from common import save_figure, table, timed, write_json
from tactile_mirror.contact import ContactSolver, Pad, ridge_model, simulate
from tactile_mirror.geometry import RidgeGeometry
from tactile_mirror.kernels import contact_simd_path, use_baseline
from tactile_mirror.lab.measure import cpu_model

#: ``--quick``: the paper's scenes on this coarse mesh, sampled at this rate.
QUICK_GEOMETRY = RidgeGeometry(mesh_size=0.6e-3, contact_mesh_size=0.15e-3)
QUICK_FS = 250.0


def paper(name, quick=False, **overrides):
    """``tm.scenes.paper(name, **overrides)``; with ``quick`` on :data:`QUICK_GEOMETRY`, sampled at
    :data:`QUICK_FS`."""
    if quick:
        overrides = {"geometry": QUICK_GEOMETRY, "fs": QUICK_FS, **overrides}
    return tm.scenes.paper(name, **overrides)


def bench_backends(quick):
    """The compiled solver against the Python reference, same steps, same process."""
    scene = paper("fig6", quick)
    model = ridge_model(scene.geometry)
    y, z = scene.plate_motion()
    plate_z = model.geometry.height - z
    mu, mu_k = scene.friction, scene.friction * scene.kinetic_ratio

    def per_step(backend):
        s = ContactSolver(model, mu, mu_kinetic=mu_k, backend=backend)
        dt = np.empty(y.size)
        clock = time.perf_counter
        for i in range(y.size):
            t0 = clock()
            s.step(y[i], plate_z[i])
            dt[i] = clock() - t0
        return dt

    runs = {b: min((per_step(b) for _ in range(1 if quick else 2)), key=np.sum) for b in ("python", "cpp")}
    py, cc = runs["python"], runs["cpp"]
    simd_path = contact_simd_path()
    use_baseline(True)  # the same kernel compiled for the x86-64 baseline (SSE2)
    try:
        cb = min((per_step("cpp") for _ in range(1 if quick else 2)), key=np.sum)
        t_cb, _ = timed(lambda: simulate(scene, backend="cpp", stepping="every"), repeat=2 if quick else 3)
    finally:
        use_baseline(False)
    rows = [[f"mean per step (fig6, {y.size} steps)", f"{py.mean() * 1e6:.0f} us",
             f"{cc.mean() * 1e6:.1f} us",
             f"{py.mean() / cc.mean():.1f}x"],
            ["median per step", f"{np.median(py) * 1e6:.0f} us", f"{np.median(cc) * 1e6:.1f} us",
             f"{np.median(py) / np.median(cc):.1f}x"],
            ["p99 per step", f"{np.percentile(py, 99) * 1e6:.0f} us", f"{np.percentile(cc, 99) * 1e6:.0f} us",
             f"{np.percentile(py, 99) / np.percentile(cc, 99):.1f}x"],
            ["cpp kernels compiled for the baseline (SSE2): mean / median per step", "",
             f"{cb.mean() * 1e6:.1f} / {np.median(cb) * 1e6:.1f} us",
             f"{py.mean() / cb.mean():.1f}x / {np.median(py) / np.median(cb):.1f}x"]]
    t_py, _ = timed(lambda: simulate(scene, backend="python", stepping="every"), repeat=1 if quick else 2)
    t_cc, _ = timed(lambda: simulate(scene, backend="cpp", stepping="every"), repeat=2 if quick else 3)
    rows.append([f"simulate(fig6) end to end (signals; cpp kernels: {simd_path})", f"{t_py:.2f} s", f"{t_cc:.3f} s",
                 f"{t_py / t_cc:.1f}x"])
    rows.append(["simulate(fig6), cpp kernels compiled for the baseline", "", f"{t_cb:.3f} s", f"{t_py / t_cb:.1f}x"])
    c_py, _ = timed(lambda: simulate(scene, backend="python", stepping="every"), repeat=1, clock=time.process_time)
    c_cc, _ = timed(lambda: simulate(scene, backend="cpp", stepping="every"), repeat=2 if quick else 3,
                    clock=time.process_time)
    rows.append(["simulate(fig6), CPU time of this process", f"{c_py:.2f} s", f"{c_cc:.3f} s", f"{c_py / c_cc:.1f}x"])
    six = dataclasses.replace(scene, n_ridges=6)
    ys, zs = six.plate_motion()

    def pad_steps(backend, n):
        pad = Pad.from_scene(six, backend=backend)
        dt = np.empty(n)
        for i in range(n):
            t0 = time.perf_counter()
            pad.advance(ys[i], zs[i])
            dt[i] = time.perf_counter() - t0
        return dt

    n6 = ys.size
    p6 = pad_steps("cpp", n6)
    q6 = pad_steps("python", 50 if quick else n6)
    rows.append([f"6-ridge pad step, mean over fig6 ({n6} steps; python: first {q6.size})",
                 f"{q6.mean() * 1e3:.2f} ms", f"{p6.mean() * 1e3:.3f} ms", f"{q6.mean() / p6[:q6.size].mean():.1f}x"])
    spread = f"{np.median(p6) * 1e3:.3f} / {np.percentile(p6, 99) * 1e3:.2f} / {p6.max() * 1e3:.2f} ms"
    rows.append(["6-ridge pad step, median / p99 / max", "", spread, ""])
    table(f"Contact solver: compiled kernel (backend='cpp', dense kernels: {simd_path}) against the Python "
          "reference (goals: per step >= 20x, fig6 end to end >= 8x, 6-ridge pad step <= 0.5 ms). simulate() runs "
          "the whole trajectory in compiled blocks; the per-step rows go through ContactSolver.step / Pad.advance",
          ["what", "python", "cpp", "speed-up"], rows)


def bench_realtime(duration, quick=False):
    """The paced loop at 1 kHz against the simulated 6-ridge FEM pad: open loop (the pad
    stands still, the finger slips: the solver's worst case, breakaway cascades over the whole
    contact) and closed loop with the default law (what hardware in the loop runs); the
    default pad on one and two threads, and :meth:`FemPad.realtime` (coarser contact
    elements)."""
    from tactile_mirror.contact.plants import FemPad
    from tactile_mirror.lab.loop.envelope import REPORT_PATHS, law_controllers
    from tactile_mirror.lab.loop.experiment import PLANTS, default_weights
    from tactile_mirror.loop.scene import LoopScene, run_scene
    from tactile_mirror.loop.stage import StageLimits

    rows = []
    weights = default_weights("fem", 1000.0)
    limits = StageLimits(-0.02, 0.02, 0.03, 1.0)

    def run(label, sc, plant, controller=None, shear_weights=None):
        r = run_scene(sc, weights, controller, limits, n_ridges=plant.n_ridges, shear_weights=shear_weights,
                      plant=plant, realtime=True)
        res = r.run
        tp, lp = res.tick_percentiles(), res.latency_percentiles()
        rows.append([label, len(res.t), r.gross_slips, f"{tp['p50']:.0f} / {tp['p99']:.0f} / {tp['max']:.0f}",
                     f"{lp['p50']:.0f} / {lp['p99']:.0f}", res.overruns, res.late_starts])

    pads = {"default pad": lambda sc: FemPad(6, mu=sc.mu, fs=sc.fs),
            "default pad, 2 threads": lambda sc: FemPad(6, mu=sc.mu, fs=sc.fs, threads=2),
            "FemPad.realtime()": lambda sc: FemPad.realtime(6, mu=sc.mu, fs=sc.fs)}
    for n_ridges in (6,) if quick else (1, 6):
        sc = LoopScene(seed=0, duration=duration, press=0.5, plant="fem", trajectory=PLANTS["fem"]["trajectory"])
        run(f"open loop, {n_ridges} ridge{'s' if n_ridges > 1 else ''}, experiment path, default pad", sc,
            FemPad(n_ridges, fs=sc.fs))
    laws, design = law_controllers(weights, 1000.0, limits, 0.001, 0.002, 6, "fem")
    laws_pads = (("open loop", list(pads)), ("default", ["default pad", "FemPad.realtime()"]))
    if quick:
        laws_pads = (("open loop", ["default pad, 2 threads"]), ("default", ["FemPad.realtime()"]))
    for law, pad_names in laws_pads:
        for pad_name in pad_names:
            for v in (0.005,) if quick else (0.005, 0.02):
                sc = LoopScene(seed=REPORT_PATHS.first_seed, duration=duration, fs=1000.0, plant="fem",
                               trajectory=REPORT_PATHS.trajectory(v))
                run(f"{law}, 6 ridges, report path {v * 1e3:g} mm/s, {pad_name}", sc, pads[pad_name](sc), laws[law],
                    design.shear_weights)
    table(f"Paced loop (realtime=True) at 1 kHz against the simulated FEM pad, {duration:g} s "
          "(tick: plant + pipeline + stage; goal: p99 below one tick, 1000 us). Open loop the finger slips "
          "over the still pad: every gross slip is a breakaway cascade over the whole contact, several "
          "refactorisations in one tick; closed loop the default law keeps the contact stuck. FemPad.realtime(): "
          "contact elements of 0.2 mm instead of 0.05 mm",
          ["run", "ticks", "gross slips", "tick p50 / p99 / max [us]", "pipeline latency p50 / p99 [us]",
           "overruns", "late starts"], rows)


def bench_realtime_accuracy(duration, figure_path=None, quick=False):
    """What the real-time pad gives up: the open-loop report paths (finger over a still
    pad, 6 ridges) stepped as fast as possible through pads whose contact elements are
    0.2 (FemPad.realtime(); the largest the default mesh allows: 41 contact nodes), 0.1
    (81) and 0.05 mm (the default, 161), the smallest and largest also on two threads
    (sizes in between give one of these meshes)
    against a reference pad with contact elements of 0.025 mm: their strips' L - R stress
    and tangential force compared, with the plant's own time per tick. ``figure_path``:
    also the figure of error and tick time against the contact nodes. ``quick``: against the
    default pad (0.05 mm), the real-time pad and 0.1 mm, one path."""
    from tactile_mirror.contact.plants import REALTIME_CONTACT_MESH_SIZE, FemPad
    from tactile_mirror.lab.loop.envelope import REPORT_PATHS
    from tactile_mirror.loop.scene import LoopScene, gross_slip_events, scene_finger

    def sized(h, **kw):
        return lambda sc: FemPad(6, mu=sc.mu, fs=sc.fs, geometry=RidgeGeometry(contact_mesh_size=h), **kw)

    default_h = RidgeGeometry().contact_mesh_size
    ref_h = default_h if quick else 0.025e-3
    pads = {f"reference ({ref_h * 1e3:g} mm)": (ref_h, 1, sized(ref_h))}
    for h in (REALTIME_CONTACT_MESH_SIZE, 0.1e-3) + (() if quick else (default_h,)):
        label = ("FemPad.realtime()" if h == REALTIME_CONTACT_MESH_SIZE else
                 "default pad" if h == default_h else "contact elements") + f" ({h * 1e3:g} mm)"
        pads[label] = (h, 1, sized(h))
    if not quick:
        pads[f"default pad ({default_h * 1e3:g} mm), 2 threads"] = (default_h, 2, sized(default_h, threads=2))
    pads["FemPad.realtime(threads=2)"] = (REALTIME_CONTACT_MESH_SIZE, 2, sized(REALTIME_CONTACT_MESH_SIZE, threads=2))
    rows, points = [], []
    for v in (0.005,) if quick else (0.005, 0.02):
        sc = LoopScene(seed=REPORT_PATHS.first_seed, duration=duration, fs=1000.0, plant="fem",
                       trajectory=REPORT_PATHS.trajectory(v))
        finger = scene_finger(sc)
        ref = None
        for name, (h, threads, make) in pads.items():
            plant = make(sc)
            n = finger.size
            dt, lr, fy, sf = np.empty(n), np.empty((n, 6)), np.empty(n), np.empty((n, 6))
            for k in range(n):
                t0 = time.perf_counter()
                st = plant.advance(float(finger[k]))
                dt[k] = time.perf_counter() - t0
                lr[k] = st.stress[:, 0] - st.stress[:, 1]
                fy[k], sf[k] = st.force_y, st.slip_fraction
            if ref is None:
                ref = (lr, fy)
            e_lr = np.sqrt(np.mean((lr - ref[0]) ** 2)) / np.max(np.abs(ref[0]))
            e_fy = np.sqrt(np.mean((fy - ref[1]) ** 2)) / np.max(np.abs(ref[1]))
            nodes = plant.pad.solvers[0].model.n_nodes
            is_ref = name.startswith("reference")
            rows.append([f"{v * 1e3:g} mm/s", name, nodes,
                         f"{np.median(dt) * 1e6:.0f} / {np.percentile(dt, 99) * 1e6:.0f} / {dt.max() * 1e6:.0f}",
                         f"{np.mean(dt) * 1e6:.0f}", gross_slip_events(sf.T),
                         "-" if is_ref else f"{100 * e_lr:.1f} %", "-" if is_ref else f"{100 * e_fy:.2f} %"])
            points.append({"v": v, "h": h, "threads": threads, "nodes": nodes, "p50": np.median(dt),
                           "p99": np.percentile(dt, 99), "max": dt.max(), "mean": dt.mean(),
                           "gross_slips": gross_slip_events(sf.T), "lr": None if is_ref else e_lr,
                           "fy": None if is_ref else e_fy})
    table(f"The FEM pad's contact resolution against its cost, open loop (finger over a still pad), report paths, "
          f"6 ridges, {duration:g} s, the plant stepped as fast as possible (errors: rms over all ticks and ridges, "
          f"relative to the {'reference' if not quick else 'default pad'}'s peak)",
          ["path", "pad", "contact nodes a ridge", "plant tick p50 / p99 / max [us]", "mean [us]", "gross slips",
           "L - R stress error", "F_y error"], rows)
    if figure_path:
        realtime_figure(points, figure_path, default_h, REALTIME_CONTACT_MESH_SIZE)
        from tactile_mirror.lab.measure import environment

        write_json(os.path.splitext(figure_path)[0] + ".json",
                   {"environment": environment(), "duration_s": duration, "default_contact_mesh_size": default_h,
                    "realtime_contact_mesh_size": REALTIME_CONTACT_MESH_SIZE,
                    "rows": [{k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in p.items()}
                             for p in points]}, indent=1)


def realtime_figure(points, path, default_h, realtime_h):
    """Left: the plant's tick p99 against the contact nodes a ridge, the 1 kHz tick marked;
    right: the strips' L - R error against the same, per report path (one thread)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_t, ax_e) = plt.subplots(1, 2, figsize=(11, 4.2))
    for v, marker in ((0.005, "o"), (0.02, "s")):
        pts = sorted((p for p in points if p["v"] == v and p["threads"] == 1), key=lambda p: p["nodes"])
        nodes = [p["nodes"] for p in pts]
        ax_t.semilogy(nodes, [p["p99"] * 1e3 for p in pts], marker + "-", label=f"p99, {v * 1e3:g} mm/s path")
        ax_t.semilogy(nodes, [p["max"] * 1e3 for p in pts], marker + ":", color="0.6", ms=4,
                      label=f"max, {v * 1e3:g} mm/s path")
        err = [(p["nodes"], p["lr"] * 100) for p in pts if p["lr"] is not None]
        ax_e.plot(*zip(*err), marker + "-", label=f"{v * 1e3:g} mm/s path")
    for ax in (ax_t, ax_e):
        for h, text in ((default_h, "default"), (realtime_h, "FemPad.realtime()")):
            n = next(p["nodes"] for p in points if p["h"] == h)
            ax.axvline(n, color="0.8", lw=3, zorder=0)
            ax.annotate(text, (n, 0.03), xycoords=("data", "axes fraction"), ha="left", va="bottom", fontsize=8,
                        rotation=90, xytext=(3, 0), textcoords="offset points")
        ax.set_xlabel("contact nodes a ridge")
        ax.grid(True, which="both", alpha=0.3)
    ax_t.axhline(1.0, color="r", lw=1)
    ax_t.annotate("one tick at 1 kHz", (ax_t.get_xlim()[0], 1.0), va="bottom", fontsize=8, color="r")
    ax_t.set(ylabel="plant tick, ms (6 ridges, one thread)", title="Open loop: the slowest ticks")
    ax_e.set(ylabel="rms error of the strips' L - R, % of peak", ylim=(0, None),
             title="Against contact elements of 0.025 mm")
    ax_t.legend(fontsize=7)
    ax_e.legend(fontsize=7)
    fig.suptitle("The FEM pad's contact resolution: real time against accuracy (finger over a still pad)",
                 fontsize=10)
    fig.tight_layout()
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    try:
        save_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)
    print(f"\nFigure written to {path}")


def bench_fig6(quick=False):
    scene = paper("fig6", quick)
    geom = scene.geometry
    ridge_model.cache_clear()
    t0 = time.perf_counter()
    model = ridge_model(geom)
    setup = time.perf_counter() - t0
    t_run, res = timed(lambda: simulate(scene))
    # CPU time of this process: what one core costs, whatever else runs
    cpu, _ = timed(lambda: simulate(scene), clock=time.process_time)
    rows = [["model setup (mesh, assembly, condensation), first run", f"{setup:.2f} s"],
            ["model setup, cached", f"{timed(lambda: ridge_model(geom))[0] * 1e6:.1f} us"],
            [f"simulate fig6: {res.t.size} steps at {scene.fs / 1e3:g} kHz, 1 ridge, signals",
             (f"{t_run:.2f} s "
             f"({t_run / res.t.size * 1e3:.3f} ms/step)")],
            ["same, CPU time of the process (one core)", f"{cpu:.2f} s ({cpu / res.t.size * 1e3:.3f} ms/step)"],
            ["Newton (active-set) iterations per step", f"{res.newton_iterations / res.t.size:.2f}"],
            ["gross slip", f"{res.slip_time:.3f} s"],
            ["contact nodes / DOFs / elements", f"{model.n_nodes} / {model.n_dofs} / {model.n_elements}"]]
    six = dataclasses.replace(scene, n_ridges=6)
    t6, r6 = timed(lambda: simulate(six), repeat=1)
    rows.append([f"simulate fig6 with a 6-ridge pad ({r6.t.size} steps)", f"{t6:.2f} s"])
    table("fig6 end to end (goal: <= 1 s on one core)", ["what", "measured"], rows)


def bench_reduced_vs_full(n_steps, quick=False):
    model = ridge_model(QUICK_GEOMETRY if quick else RidgeGeometry())
    H = model.geometry.height
    t = np.arange(n_steps) / 1000.0 + 1.0
    y = 0.2e-3 * (t - 0.5)
    z = H - 30e-6

    def run(reduced):
        s = ContactSolver(model, tm.scenes.DEFAULT_FRICTION, reduced=reduced)
        s.step(0.0, H - 15e-6)
        s.step(0.0, z)
        out = [s.step(yy, z) for yy in y]
        return out

    t_red, a = timed(lambda: run(True), repeat=3)
    t_full, b = timed(lambda: run(False), repeat=1)
    err = max(np.max(np.abs(x.forces - w.forces)) / np.max(np.abs(w.forces)) for x, w in zip(a, b))
    table(f"Reduced (condensed) vs unreduced (full sparse KKT) solves, {n_steps} sliding steps",
          ["solver", "time per step", "max relative difference of the contact forces"],
          [["unreduced", f"{t_full / n_steps * 1e3:.2f} ms", ""],
           ["reduced", f"{t_red / n_steps * 1e3:.3f} ms", f"{err:.1e}"],
           ["speed-up", f"{t_full / t_red:.0f}x (goal >= 30x)", ""]])


def bench_outputs(quick=False):
    base = paper("fig6", quick)
    rows = []
    for outs in (("slip",), ("forces", "slip"), ("stress",), ("forces", "slip", "stress", "signals"),
                 ("forces", "slip", "stress", "signals", "state")):
        s = base.with_outputs(*outs)
        tt, _ = timed(lambda s=s: simulate(s), repeat=2, clock=time.process_time)
        rows.append([" + ".join(outs), f"{tt:.3f} s"])
    s = dataclasses.replace(base.with_outputs("slip"), stop_after_slip=0.05)
    tt, r = timed(lambda: simulate(s), repeat=2, clock=time.process_time)
    rows.append([f"slip, stop 50 ms after gross slip ({r.t.size} steps)", f"{tt:.3f} s"])
    for times in ((1.0,), (0.6, 0.8, 1.0, 1.2, 1.4)):
        s = dataclasses.replace(base.with_outputs("slip", "fields"), field_times=times)
        tt, _ = timed(lambda s=s: simulate(s), repeat=1, clock=time.process_time)
        rows.append([f"slip + full stress fields at {len(times)} time(s)", f"{tt:.3f} s"])
    table(f"Cost follows the request (fig6 scene, {base.n_samples} steps; the contact solve is shared by all "
          "outputs, the rest is paid only when asked)", ["outputs", "CPU time"], rows)


def bench_mesh(quick):
    """Mesh size against strip-stress error, both readings of the strips against the projected
    reference (the full study, with the error split by phase and the slip time:
    ``bench/mesh_study.py``)."""
    sizes = (0.6e-3, 0.5e-3) if quick else (0.4e-3, 0.3e-3, 0.2e-3, 0.15e-3, 0.1e-3)
    ref_size = 0.4e-3 if quick else 0.075e-3
    base = tm.scenes.paper("fig6", duration=1.3, outputs=frozenset({"stress"}))

    def run(h, stress_recovery):
        g = RidgeGeometry(mesh_size=h, contact_mesh_size=h / 4, stress_recovery=stress_recovery)
        m = ridge_model(g)
        setup = m.setup_seconds  # measured when the model was built (a cached model costs ~1 us)
        tt, r = timed(lambda: simulate(dataclasses.replace(base, geometry=g)), repeat=1)
        return m, setup, tt, r

    _m_ref, _, _, ref = run(ref_size, "projected")
    scale = np.max(np.abs(ref.stress))
    i_fix = 900  # t = 0.9 s: indented and sheared, little slip yet
    rows = []
    for h in (*sizes, ref_size):
        m, setup, tt, r = run(h, "pointwise")
        _, _, _, rp = run(h, "projected")
        ref_row = h == ref_size

        def err(x):
            return np.sqrt(np.mean((x.stress - ref.stress) ** 2)) / scale

        fixed = np.max(np.abs(rp.stress[..., i_fix] - ref.stress[..., i_fix])) / scale
        rows.append([f"{h * 1e3:.3f}", f"{h / 4 * 1e3:.4f}", m.n_dofs, m.n_nodes, f"{setup:.2f} s", f"{tt:.2f} s",
                     f"{err(r):.1e}", "ref." if ref_row else f"{err(rp):.1e}",
                     "ref." if ref_row else f"{fixed:.1e}"])
    table(f"Mesh size against strip-stress error and run time (fig6 to 1.3 s; reference h = {ref_size * 1e3} mm "
          "read projected; errors relative to its peak stress)",
          ["h [mm]", "contact h [mm]", "DOFs", "contact nodes", "setup", "simulate", "rms error, pointwise (default)",
           "rms error, projected", "projected, error at t = 0.9 s"], rows)


def _both(scene, repeat):
    """``every`` and ``auto`` on one scene, the Python backend, this process."""
    te, e = timed(lambda: simulate(scene, backend="python", stepping="every"), repeat=1)
    ta, a = timed(lambda: simulate(scene, backend="python", stepping="auto"), repeat=repeat)
    err = float(np.max(np.abs(e.stress - a.stress)) / np.max(np.abs(e.stress)))
    same_states = e.node_state is None or bool(np.array_equal(e.node_state, a.node_state))
    return te, ta, e, a, err, e.slip_time == a.slip_time, same_states


def _slip(t):
    return "none" if t is None else f"{t:.3f} s"


def bench_stepping(quick):
    """Time against error of the event-driven stepping ("auto") and the per-sample
    reference ("every"), both in the Python backend, in this process."""
    out = frozenset({"stress", "slip", "state", "forces"})
    rep = 1 if quick else 2
    rows = []
    named = [("fig6", paper("fig6", quick, outputs=out)), ("fig7", paper("fig7", quick, outputs=out)),
             ("fig8", paper("fig8", quick, outputs=out))]
    if not quick:  # (the Python backend's 6-ridge pad: most of a quick run)
        named.append(("fig6, 6-ridge pad", paper("fig6", quick, outputs=out, n_ridges=6)))
    ratios = {}
    for name, sc in named:
        te, ta, e, a, err, same_slip, same_states = _both(sc, rep)
        ratios[name] = te / ta
        rows.append([name, f"{te:.2f} s", f"{ta:.3f} s", f"{te / ta:.1f}x", f"{e.solves} / {a.solves}",
                     f"{a.events}", f"{err:.1e}", f"{_slip(e.slip_time)} / {_slip(a.slip_time)}",
                     "yes" if same_states else "NO"])
    n_random = 2 if quick else 40
    randoms = tm.scenes.random(n_random, seed=17, friction=(0.3, 1.2), indent=(15e-6, 40e-6),
                               slide_speed=(0.1e-3, 0.6e-3), stop_probability=0.6, stop_length=(0.02, 0.5),
                               duration=2.5, outputs=out,
                               **({"geometry": QUICK_GEOMETRY, "fs": QUICK_FS} if quick else {}))
    tot_e = tot_a = 0.0
    worst = 0.0
    all_slip = all_states = True
    per_scene = []
    for k, sc in enumerate(randoms):
        te, ta, e, a, err, same_slip, same_states = _both(sc, 1)
        tot_e += te
        tot_a += ta
        worst = max(worst, err)
        all_slip &= same_slip
        all_states &= same_states
        stop = f"{sc.stops[0][1] - sc.stops[0][0]:.2f} s" if sc.stops else "-"
        per_scene.append([k, f"{sc.friction:.2f}", f"{sc.indent_speed * 0.5 * 1e6:.0f} um",
                          f"{sc.slide_speed * 1e3:.2f} mm/s", stop, f"{te:.2f} s", f"{ta:.3f} s",
                          f"{e.solves} / {a.solves}", a.events, f"{err:.1e}",
                          f"{_slip(e.slip_time)} / {_slip(a.slip_time)}", "yes" if same_states else "NO"])
    rows.append([f"{n_random} random scenes (total)", f"{tot_e:.2f} s", f"{tot_a:.2f} s", f"{tot_e / tot_a:.1f}x",
                 "", "", f"{worst:.1e} (worst)", "all equal" if all_slip else "DIFFER",
                 "yes" if all_states else "NO"])
    header = ["scene", "every", "auto", "speed-up", "solves every / auto", "events", "stress error / peak",
              "slip time every / auto", "node states equal"]
    table("Contact stepping, time against error: 'every' (solve at every sample, the reference) and 'auto' "
          "(solve at events only), Python backend, same process (error: max strip-stress difference of auto "
          "against every over all strips and samples, relative to the peak)", header, rows)
    table("Random scenes (seed 17; friction 0.3-1.2, indent 15-40 um, slide 0.1-0.6 mm/s, stops of "
          f"0.02-0.5 s in 60 % of them; 2.5 s at {randoms[0].fs / 1e3:g} kHz)",
          ["#", "friction", "indent", "slide", "stop", "every", "auto", "solves every / auto", "events",
           "error / peak", "slip time every / auto", "states equal"], per_scene)

    # the goals
    goals = []
    for name in [n for n in ("fig6", "fig6, 6-ridge pad") if n in ratios]:
        goals.append([f"{name}: auto against every end to end", f"{ratios[name]:.1f}x", ">= 10x"])
    slip = frozenset({"slip"})
    plain = paper("fig6", quick, outputs=slip, duration=2.0)
    stopped = paper("fig6", quick, outputs=slip, duration=2.5, stops=((1.0, 1.5),))
    t_plain, r_plain = timed(lambda: simulate(plain, backend="python"), repeat=rep + 1)
    t_stop, r_stop = timed(lambda: simulate(stopped, backend="python"), repeat=rep + 1)
    goals.append(["fig6 with a 0.5 s stop (1.0-1.5 s) against without, auto",
                  (f"{t_stop / t_plain:.2f}x ({t_stop:.3f} / {t_plain:.3f} s; solves {r_stop.solves} / "
                  f"{r_plain.solves})"), "same cost"])
    hi = dataclasses.replace(plain, fs=10 * plain.fs)
    t_hi, r_hi = timed(lambda: simulate(hi, backend="python"), repeat=rep)
    rates = f"{hi.fs / 1e3:g} kHz against {plain.fs / 1e3:g} kHz"
    goals.append([f"fig6 at {rates}, auto", (f"{t_hi / t_plain:.2f}x ({t_hi:.3f} / {t_plain:.3f} s; "
                  f"solves {r_hi.solves} / {r_plain.solves}; slip {_slip(r_hi.slip_time)} / "
                  f"{_slip(r_plain.slip_time)})"), "<= 1.5x"])
    if not quick:
        te1, _ = timed(lambda: simulate(plain, backend="python", stepping="every"), repeat=1)
        te10, _ = timed(lambda: simulate(hi, backend="python", stepping="every"), repeat=1)
        goals.append([f"fig6 at {rates}, every", f"{te10 / te1:.2f}x ({te10:.2f} / {te1:.2f} s)",
                      "(about 10x)"])
    table("Goals of the event-driven stepping (Python backend; the compiled solver's: 'Event stepping in the "
          "compiled solver')",
          ["what", "measured", "goal"], goals)


def figures(folder):
    from tactile_mirror.lab.plots import contact_scene_figure, save

    titles = {"fig6": "Fig. 6: no stop", "fig7": "Fig. 7: stop at A (1.00-1.05 s)",
              "fig8": "Fig. 8: stop at B (1.40-1.45 s)"}
    for name, title in titles.items():
        r = simulate(tm.scenes.paper(name))
        save(contact_scene_figure(r, title=f"{title}; gross slip at {r.slip_time:.3f} s"),
             os.path.join(folder, f"{name}.png"))
    print(f"\nFigures written to {folder}/fig6.png, fig7.png, fig8.png")


def bench_cpp_events(quick):
    """The compiled event stepping against the Python reference and against the
    compiled per-sample stepping, same process: end-to-end time, solves and events,
    and the difference of the strip stresses (relative to their peak). Returns the
    largest difference of the compiled event stepping's."""
    rows = []
    worst = 0.0
    names = ("fig6",) if quick else ("fig6", "fig7", "fig8")
    rounds = 1 if quick else 3
    for name in names:
        scene = paper(name, quick)
        ref = simulate(scene, backend="cpp", stepping="every")
        peak = np.max(np.abs(ref.stress))
        runs = [("cpp", "auto", 5), ("cpp", "every", 3), ("python", "auto", 1)]
        if name == "fig6" and not quick:
            runs.append(("python", "every", 1))
        times = {}
        for backend, stepping, rep in runs:
            t, r = timed(lambda b=backend, s=stepping: simulate(scene, backend=b, stepping=s), repeat=rep)
            times[backend, stepping] = t
            err = np.max(np.abs(r.stress - ref.stress)) / peak
            if (backend, stepping) == ("cpp", "auto"):
                worst = max(worst, float(err))
            same = r.slip_time == ref.slip_time
            rows.append([name, backend, stepping, f"{t * 1e3:.1f} ms", r.solves, r.events,
                         f"{r.slip_time:.4f} s" + ("" if same else " (differs)"), f"{err:.1e}"])
        speedup = (f"{times['cpp', 'every'] / times['cpp', 'auto']:.1f}x vs cpp every, "
                   f"{times['python', 'auto'] / times['cpp', 'auto']:.1f}x vs python auto")
        rows.append([name, "cpp auto: speed-up", "", speedup, "", "", "", ""])
        # auto cannot beat every by more than every's solves over auto's: a sample of
        # every that meets no event reuses the piece's factors (from its third sample its
        # affine response, O(n) like auto's samples between events), while each of auto's
        # solves is an event (a new piece: bordered update, unit responses, cascade)
        ra = simulate(scene, backend="cpp", stepping="auto")
        re_ = simulate(scene, backend="cpp", stepping="every")
        rows.append([name, "bound on auto vs every", "", f"every / auto solves = {re_.solves / ra.solves:.1f}x "
                     f"({re_.solves} / {ra.solves}; {ra.events} events, {ra.t.size} samples)", "", "", "", ""])
    where = ", coarse mesh, 250 Hz" if quick else ""
    table(f"Event stepping in the compiled solver (simulate, signals{where}; "
          "goals: fig6 <= 50 ms end to end with "
          "backend='cpp', stepping='auto'; auto 10x faster than every; stress difference vs cpp every <= 1e-9 of "
          "the peak)", ["scene", "backend", "stepping", "end to end", "solves", "events", "gross slip",
                        "stress diff / peak"], rows)

    # 6-ridge pad: the whole trajectory by Pad.follow, one thread against two
    six = paper("fig6", quick, n_ridges=6)
    y, ind = six.plate_motion()
    rows = []
    res = {}
    for stepping in ("auto", "every"):
        for threads in (1, 2):
            pad = Pad.from_scene(six, backend="cpp", stepping=stepping)
            pad.threads = threads

            def run(pad=pad):
                pad.reset()
                return pad.follow(y, ind)

            t, out = timed(run, repeat=rounds)
            res[stepping, threads] = out
            same = "" if threads == 1 else ("identical" if all(np.array_equal(a, b) for a, b in zip(
                out, res[stepping, 1]) if a is not None) else "DIFFERENT")
            rows.append([stepping, threads, f"{t * 1e3:.1f} ms", f"{t / y.size * 1e6:.1f} us", pad.solves,
                         pad.events, same])
    t6, r6 = timed(lambda: simulate(six, backend="cpp", stepping="auto"), repeat=rounds)
    rows.append(["simulate(6-ridge fig6), auto", 1, f"{t6 * 1e3:.1f} ms", f"{t6 / y.size * 1e6:.1f} us", r6.solves,
                 r6.events, ""])
    # per sample from Python, as the loop plants step: Pad.advance. Under the curved
    # finger ridges k and 5 - k have the same path, so the pad computes three of the six;
    # the reference steps six one-ridge pads, each at its ridge's indent, one call per
    # ridge, none shared (the work before the mirror-image sharing, plus five more calls
    # of Pad.advance from Python)
    offsets = Pad.from_scene(six).indent_offset
    for stepping in ("auto", "every"):
        best = {}
        for _ in range(rounds):
            pad = Pad.from_scene(six, backend="cpp", stepping=stepping)
            singles = [Pad.from_scene(dataclasses.replace(six, n_ridges=1), backend="cpp", stepping=stepping)
                       for _ in offsets]
            dt = np.empty(y.size)
            dr = np.empty(y.size)
            for i in range(y.size):
                t0 = time.perf_counter()
                pad.advance(y[i], ind[i])
                dt[i] = time.perf_counter() - t0
                t0 = time.perf_counter()
                for single, off in zip(singles, offsets):
                    single.advance(y[i], ind[i] - off)
                dr[i] = time.perf_counter() - t0
            for key, d in (("pad", dt), ("ref", dr)):
                if key not in best or d.mean() < best[key].mean():
                    best[key] = d
        dt, dr = best["pad"], best["ref"]
        rows.append([f"Pad.advance per sample ({stepping}): mean / p99 / max", 1,
                     f"{dt.mean() * 1e3:.3f} / {np.percentile(dt, 99) * 1e3:.3f} / {dt.max() * 1e3:.2f} ms", "",
                     pad.solves, pad.events, ""])
        rows.append([f"six one-ridge pads stepped one by one, none shared ({stepping}): mean / p99 / max", 1,
                     f"{dr.mean() * 1e3:.3f} / {np.percentile(dr, 99) * 1e3:.3f} / {dr.max() * 1e3:.2f} ms", "",
                     sum(p.solves for p in singles), sum(p.events for p in singles),
                     f"Pad.advance {dr.mean() / dt.mean():.1f}x faster (mean)"])
    best2 = None
    for _ in range(rounds):  # the closed loop's tick with the pad's worker thread
        pad = Pad.from_scene(six, backend="cpp", stepping="auto")
        pad.threads = 2
        dt = np.empty(y.size)
        for i in range(y.size):
            t0 = time.perf_counter()
            pad.advance(y[i], ind[i])
            dt[i] = time.perf_counter() - t0
        if best2 is None or dt.mean() < best2.mean():
            best2 = dt
    rows.append(["Pad.advance per sample (auto): mean / median / p99 / max", 2,
                 f"{best2.mean() * 1e3:.3f} / {np.median(best2) * 1e3:.3f} / {np.percentile(best2, 99) * 1e3:.3f} / "
                 f"{best2.max() * 1e3:.2f} ms", "", pad.solves, pad.events, "worker thread kept by the pad"])
    table(f"6-ridge pad over fig6 ({y.size} samples), compiled event stepping: the ridges are independent, "
          "threads=2 shares them with a second thread, one at a time; a ridge with the path of an earlier "
          "one (its mirror image) shares its computation (goal: a pad step <= 0.5 ms)",
          ["stepping", "threads", "whole trajectory", "per sample", "solves", "events", "notes"], rows)

    # cost against the sample rate and against a stop
    rows = []
    base = paper("fig6", quick)
    hi = dataclasses.replace(base, fs=10 * base.fs)
    low_rate, high_rate = f"{base.fs / 1e3:g} kHz", f"{hi.fs / 1e3:g} kHz"
    for label, sc in ((f"fig6 at {low_rate}", base), (f"fig6 at {high_rate}", hi),
                      ("fig6 with a 0.5 s stop at 1.0 s",
                       paper("fig6", quick, stops=((1.0, 1.5),), duration=2.5))):
        ta, ra = timed(lambda sc=sc: simulate(sc, backend="cpp", stepping="auto"), repeat=rounds)
        te, re_ = timed(lambda sc=sc: simulate(sc, backend="cpp", stepping="every"), repeat=1)
        rows.append([label, ra.t.size, f"{ta * 1e3:.1f} ms", ra.solves, ra.events, f"{te * 1e3:.1f} ms",
                     re_.solves])
    ratio = {}
    n_best = 2 if quick else 5
    for label, sc in ((low_rate, base), (high_rate, hi)):
        ratio[label], _ = timed(lambda sc=sc: simulate(sc, backend="cpp", stepping="auto"), repeat=n_best)
    rows.append([f"{high_rate} against {low_rate}, auto (best of {n_best} each)", "",
                 f"{ratio[high_rate] / ratio[low_rate]:.2f}x", "", "", "", ""])
    table("Compiled event stepping: cost against the sample rate and a stop (goals: 10 kHz within 1.5x of 1 kHz "
          "with auto; a 0.5 s stop costs nothing; simulate reads proj @ lam per sample, O(q) between events)",
          ["scene", "samples", "auto", "auto solves", "events", "every", "every solves"], rows)
    return worst


def main(argv=None) -> float:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true",
                   help="small runs of every table (coarse mesh, 250 Hz, short paced runs): a smoke run")
    p.add_argument("--figures", default=None,
                   help="folder for the Fig. 6-8 PNGs and realtime_pad.png (default: none)")
    p.add_argument("--solver-only", action="store_true",
                   help="only the compiled-against-Python solver table and the paced loop")
    p.add_argument("--stepping-only", action="store_true",
                   help="only the 'every' against 'auto' stepping tables (compiled and Python solvers)")
    p.add_argument("--realtime-only", action="store_true",
                   help="only the paced loop and the real-time pad's accuracy")
    args = p.parse_args(argv)
    quick = args.quick
    print(f"CPU: {cpu_model()} ({os.cpu_count()} logical cores)")
    if quick:
        g = QUICK_GEOMETRY
        print(f"--quick: the paper's scenes on a coarse mesh (h = {g.mesh_size * 1e3:g} mm, contact "
              f"{g.contact_mesh_size * 1e3:g} mm) at {QUICK_FS:g} Hz; paced runs of 0.7 s")
    paced = 0.7 if quick else 3.0
    if args.stepping_only:
        worst = bench_cpp_events(quick)
        bench_stepping(quick)
        return worst
    rt_figure = os.path.join(args.figures, "realtime_pad.png") if args.figures else None
    if args.realtime_only:
        bench_realtime(paced, quick)
        bench_realtime_accuracy(paced, rt_figure, quick)
        return float("nan")
    bench_backends(quick)
    bench_realtime(paced, quick)
    bench_realtime_accuracy(paced, rt_figure, quick)
    worst = bench_cpp_events(quick)
    if args.solver_only:
        return worst
    bench_fig6(quick)
    bench_reduced_vs_full(4 if quick else 200, quick)
    bench_outputs(quick)
    bench_mesh(quick)
    bench_stepping(quick)
    if args.figures:
        figures(args.figures)
    return worst


if __name__ == "__main__":
    main()
