"""Benchmarks of the contact simulation.

    python bench/bench_contact.py [--quick] [--figures DIR]

Prints markdown tables: the paper's fig6 scene end to end at 1 kHz, reduced against
unreduced solves of the same steps, cost against the outputs a scene asks for, and mesh
size against strip-stress error and run time; writes Figs. 6-8 as PNG into DIR.
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
from _common import table, timed
from tactile_mirror.contact import ContactSolver, RidgeGeometry, ridge_model, simulate


def bench_fig6():
    scene = tm.scenes.paper("fig6")
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
            [f"simulate fig6: {res.t.size} steps at 1 kHz, 1 ridge, signals", (f"{t_run:.2f} s "
             f"({t_run / res.t.size * 1e3:.3f} ms/step)")],
            ["same, CPU time of the process (one core)", f"{cpu:.2f} s ({cpu / res.t.size * 1e3:.3f} ms/step)"],
            ["Newton (active-set) iterations per step", f"{res.newton_iterations / res.t.size:.2f}"],
            ["gross slip", f"{res.slip_time:.3f} s"],
            ["contact nodes / DOFs / elements", f"{model.n_nodes} / {model.n_dofs} / {model.n_elements}"]]
    six = dataclasses.replace(scene, n_ridges=6)
    t6, r6 = timed(lambda: simulate(six), repeat=1)
    rows.append([f"simulate fig6 with a 6-ridge pad ({r6.t.size} steps)", f"{t6:.2f} s"])
    table("fig6 end to end (goal: <= 1 s on one core)", ["what", "measured"], rows)


def bench_reduced_vs_full(n_steps):
    model = ridge_model(RidgeGeometry())
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


def bench_outputs():
    base = tm.scenes.paper("fig6")
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
    table("Cost follows the request (fig6 scene, 2000 steps; the contact solve is shared by all outputs, the rest is paid only when asked)", ["outputs", "CPU time"], rows)


def bench_mesh(quick):
    sizes = (0.4e-3, 0.3e-3, 0.2e-3) if quick else (0.4e-3, 0.3e-3, 0.2e-3, 0.15e-3, 0.1e-3)
    ref_size = 0.075e-3
    base = tm.scenes.paper("fig6", duration=1.3, outputs=frozenset({"stress"}))

    def run(h):
        g = RidgeGeometry(mesh_size=h, contact_mesh_size=h / 4)
        m = ridge_model(g)
        setup = m.setup_seconds  # measured when the model was built (a cached model costs ~1 us)
        tt, r = timed(lambda: simulate(dataclasses.replace(base, geometry=g)), repeat=1)
        return m, setup, tt, r

    _m_ref, _, _, ref = run(ref_size)
    scale = np.max(np.abs(ref.stress))
    i_fix = 900  # t = 0.9 s: indented and sheared, little slip yet
    rows = []
    for h in (*sizes, ref_size):
        m, setup, tt, r = run(h)
        fixed = np.max(np.abs(r.stress[..., i_fix] - ref.stress[..., i_fix])) / scale
        rms = np.sqrt(np.mean((r.stress - ref.stress) ** 2)) / scale
        worst = np.max(np.abs(r.stress - ref.stress)) / scale
        ref_row = h == ref_size
        rows.append([f"{h * 1e3:.3f}", f"{h / 4 * 1e3:.4f}", m.n_dofs, m.n_nodes, f"{setup:.2f} s", f"{tt:.2f} s",
                     "ref." if ref_row else f"{fixed:.1e}", "ref." if ref_row else f"{rms:.1e}",
                     "ref." if ref_row else f"{worst:.1e}"])
    table(f"Mesh size against strip-stress error and run time (fig6 to 1.3 s; reference h = {ref_size * 1e3} mm; "
          "errors relative to the peak stress)",
          ["h [mm]", "contact h [mm]", "DOFs", "contact nodes", "setup", "simulate", "error at t = 0.9 s",
           "rms error", "max error (slip-front timing)"], rows)


def figures(folder):
    from tactile_mirror.plots import contact_scene_figure, save

    titles = {"fig6": "Fig. 6: no stop", "fig7": "Fig. 7: stop at A (1.00-1.05 s)",
              "fig8": "Fig. 8: stop at B (1.40-1.45 s)"}
    for name, title in titles.items():
        r = simulate(tm.scenes.paper(name))
        save(contact_scene_figure(r, title=f"{title}; gross slip at {r.slip_time:.3f} s"),
             os.path.join(folder, f"{name}.png"))
    print(f"\nFigures written to {folder}/fig6.png, fig7.png, fig8.png")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="fewer mesh sizes and steps")
    p.add_argument("--figures", default=None, help="folder for the Fig. 6-8 PNGs (default: none)")
    args = p.parse_args(argv)
    bench_fig6()
    bench_reduced_vs_full(50 if args.quick else 200)
    bench_outputs()
    bench_mesh(args.quick)
    if args.figures:
        figures(args.figures)


if __name__ == "__main__":
    main()
