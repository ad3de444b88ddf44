"""Mesh convergence study of the ridge model: strip-stress error against cost per mesh size.

    python bench/mesh_study.py [--quick] [--out docs/figures]

(``--quick``: three coarse sizes against h = 0.25 mm, a smoke run of a few seconds, not the figures.)

The paper's fig6 scene at mesh size ``h`` (contact zone ``h / 4``, the way
``RidgeGeometry`` is swept everywhere in the project), against a fine reference mesh in
the same run, the strips read with ``stress_recovery="projected"`` (the stress projected
onto continuous P1 fields) and with the default ``"pointwise"`` reading (the P2 stress at
the sample points), both against the projected reference. Error measures, each relative
to the reference's peak of what is measured:

- ``rms``: rms strip-stress error over all strips, components and samples to 1.3 s (the
  slide before gross slip, so a shift of the slip event does not dominate it);
- ``indent``: largest strip-stress error while the plate presses (0-0.5 s, no slide);
- ``slide``: largest strip-stress error while it slides, 0.5-1.3 s (partial slip spreads);
- ``L-R``: rms error of ``sigma_L - sigma_R`` (through-film stress), the paper's signal,
  relative to its own peak;
- ``peak``: error of the largest strip stress;
- ``slip``: gross slip time of the whole 2 s scene minus the reference's, ms.

Cost: DOFs, contact nodes, model setup (mesh, assembly, condensation; once per
geometry, then cached), ms per sample when the contact is solved at every sample
(``stepping="every"``, the closed loop's worst case), and ``simulate`` of the 2 s scene
with the default event stepping. The observed order is the slope of log(rms) against
log(h) over the sizes at least twice the reference's.

Writes ``OUT/mesh_study.json`` and ``OUT/mesh_study.png`` (error against cost, the
default marked) and prints the CPU model and the table (markdown). One process, one
thread: run it on a quiet machine.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import tactile_mirror as tm
from common import save_figure, table, timed, write_json
from tactile_mirror.contact import ridge_model, simulate
from tactile_mirror.geometry import RidgeGeometry
from tactile_mirror.lab.measure import cpu_model, environment

FULL_SIZES = (0.4e-3, 0.35e-3, 0.3e-3, 0.25e-3, 0.2e-3, 0.175e-3, 0.15e-3, 0.125e-3, 0.1e-3, 0.075e-3)
FULL_REFERENCE = 0.05e-3
QUICK_SIZES = (0.6e-3, 0.5e-3, 0.4e-3)
QUICK_REFERENCE = 0.25e-3
#: End of the stress comparison, s: before fig6's gross slip (about 1.47 s).
COMPARE_UNTIL = 1.3
#: End of the indent (the paper's profile: 0.5 s at 0.06 mm/s).
INDENT_END = 0.5


def lscpu_model() -> str:
    """The CPU model as ``lscpu`` names it (what /proc/cpuinfo says where lscpu is missing)."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10, check=True).stdout
    except (OSError, subprocess.SubprocessError):
        return cpu_model()
    for line in out.splitlines():
        if line.startswith("Model name:"):
            return line.split(":", 1)[1].strip()
    return cpu_model()


def geometry(h: float, stress_recovery: str = "pointwise") -> RidgeGeometry:
    return RidgeGeometry(mesh_size=h, contact_mesh_size=h / 4, stress_recovery=stress_recovery)


def stress_scene(g: RidgeGeometry):
    return tm.scenes.paper("fig6", duration=COMPARE_UNTIL, outputs=frozenset({"stress"}), geometry=g)


def run_size(h: float, repeat: int, timings: bool) -> dict:
    """The runs of one mesh size: stresses to 1.3 s read both ways, the 2 s scene's slip
    time and (``timings``) the costs, with the default reading."""
    g = geometry(h)
    model = ridge_model(g)  # the first build: its setup time is measured in it
    slip_scene = tm.scenes.paper("fig6", outputs=frozenset({"slip"}), geometry=g)
    t_sim, slip = timed(lambda: simulate(slip_scene), repeat=repeat if timings else 1)
    ms_every = None
    if timings:
        scene = stress_scene(g)
        t_every, _ = timed(lambda: simulate(scene, stepping="every"), repeat=repeat)
        ms_every = 1e3 * t_every / scene.n_samples
    return {"h_mm": h * 1e3, "dofs": int(model.n_dofs), "contact_nodes": int(model.n_nodes),
            "elements": int(model.n_elements), "setup_s": float(model.setup_seconds),
            "simulate_s": float(t_sim), "ms_per_sample_every": ms_every, "slip_time_s": slip.slip_time,
            "stress": simulate(stress_scene(geometry(h, "projected"))).stress[0],
            "stress_pointwise": simulate(stress_scene(g)).stress[0]}


def errors(s: np.ndarray, row: dict, ref: dict, fs: float) -> dict:
    r = ref["stress"]  # (strips, 3, n)
    scale = np.max(np.abs(r))
    t = np.arange(r.shape[-1]) / fs
    indent, slide = t < INDENT_END, t >= INDENT_END
    diff, diff_ref = s[0, 2] - s[1, 2], r[0, 2] - r[1, 2]
    slip = None
    if row["slip_time_s"] is not None and ref["slip_time_s"] is not None:
        slip = 1e3 * (row["slip_time_s"] - ref["slip_time_s"])
    return {"rms": float(np.sqrt(np.mean((s - r) ** 2)) / scale),
            "indent": float(np.max(np.abs(s - r)[..., indent]) / scale),
            "slide": float(np.max(np.abs(s - r)[..., slide]) / scale),
            "l_minus_r": float(np.sqrt(np.mean((diff - diff_ref) ** 2)) / np.max(np.abs(diff_ref))),
            "peak": float(np.max(np.abs(s)) / scale - 1.0),
            "slip_ms": slip}


def observed_order(rows: list, ref_h: float) -> float | None:
    """Slope of log(rms error) against log(h) over the sizes at least twice the reference's."""
    pts = [(r["h_mm"], r["errors"]["rms"]) for r in rows if r["h_mm"] >= 2 * ref_h * 1e3]
    if len(pts) < 2:
        return None
    h, e = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(h, e, 1)[0])


def figure(rows: list, default_h_mm: float, order, ref_h_mm: float, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_cost, ax_h) = plt.subplots(1, 2, figsize=(11, 4.2))
    every = [r for r in rows if r["ms_per_sample_every"] is not None]
    for ax, x_of, xlabel in ((ax_cost, lambda r: r["ms_per_sample_every"], "ms per sample (contact solved every sample)"),
                             (ax_h, lambda r: r["h_mm"], "mesh size h, mm (contact zone h / 4)")):
        pts = every if ax is ax_cost else rows
        x = [x_of(r) for r in pts]
        for key, label, style in (("rms", "rms strip stress", "o-"), ("indent", "max, indent", "s--"),
                                  ("slide", "max, slide", "^--"), ("l_minus_r", "rms of L - R", "d:")):
            ax.loglog(x, [r["errors"][key] for r in pts], style, ms=4, label=label)
        ax.loglog(x, [r["errors_pointwise"]["rms"] for r in pts], "x-", color="0.5", ms=5,
                  label="rms, pointwise reading")
        for r in pts:
            if abs(r["h_mm"] - default_h_mm) < 1e-9:
                ax.plot(x_of(r), r["errors"]["rms"], "o", ms=13, mfc="none", mec="k", mew=1.5,
                        label=f"default h = {default_h_mm:g} mm")
        ax.set_xlabel(xlabel)
        ax.grid(True, which="both", alpha=0.3)
    ax_cost.set_ylabel(f"error / reference peak (reference h = {ref_h_mm:g} mm)")
    ax_cost.legend(fontsize=7)
    ax_h.invert_xaxis()
    title = "fig6 scene: strip-stress error against cost (projected reading unless said)"
    if order is not None:
        title += f" (observed order of the rms error: {order:.2f})"
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def main(argv=None) -> float:
    """Print the table, write the files; return the projected rms error of the finest size."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true",
                   help=f"sizes {[h * 1e3 for h in QUICK_SIZES]} mm against {QUICK_REFERENCE * 1e3} mm, one repeat")
    p.add_argument("--out", default=os.path.join("docs", "figures"), help="folder of mesh_study.json and .png")
    p.add_argument("--repeat", type=int, default=None, help="timed runs per size, best taken (default 3; quick 1)")
    args = p.parse_args(argv)
    sizes, ref_h = (QUICK_SIZES, QUICK_REFERENCE) if args.quick else (FULL_SIZES, FULL_REFERENCE)
    repeat = args.repeat if args.repeat is not None else (1 if args.quick else 3)
    default_h = RidgeGeometry().mesh_size
    cpu = lscpu_model()
    print(f"CPU: {cpu} ({os.cpu_count()} logical cores)")
    t0 = time.perf_counter()
    ref = run_size(ref_h, repeat=1, timings=False)
    fs = tm.scenes.paper("fig6").fs
    rows = []
    for h in sizes:
        row = run_size(h, repeat=repeat, timings=True)
        row["errors"] = errors(row["stress"], row, ref, fs)
        row["errors_pointwise"] = errors(row["stress_pointwise"], row, ref, fs)
        rows.append(row)
        print(f"  h = {h * 1e3:g} mm done ({time.perf_counter() - t0:.0f} s)", flush=True)
    order = observed_order(rows, ref_h)
    table_rows = []
    for r in rows:
        e, ep = r["errors"], r["errors_pointwise"]
        name = f"{r['h_mm']:g}" + (" (default)" if abs(r["h_mm"] - default_h * 1e3) < 1e-9 else "")
        slip = "none" if e["slip_ms"] is None else f"{e['slip_ms']:+.0f}"
        table_rows.append([name, r["dofs"], r["contact_nodes"], f"{e['rms']:.1e}", f"{e['indent']:.1e}",
                           f"{e['slide']:.1e}", f"{e['l_minus_r']:.1e}", f"{e['peak']:+.1e}",
                           f"{ep['rms']:.1e}", f"{ep['l_minus_r']:.1e}", slip,
                           f"{r['ms_per_sample_every']:.2f}", f"{r['simulate_s'] * 1e3:.0f}", f"{r['setup_s']:.2f}"])
    table_rows.append([f"{ref_h * 1e3:g} (reference)", ref["dofs"], ref["contact_nodes"], "", "", "", "", "", "", "",
                       f"slip at {ref['slip_time_s']:.3f} s", "", f"{ref['simulate_s'] * 1e3:.0f}",
                       f"{ref['setup_s']:.2f}"])
    table(f"Mesh study, fig6 scene (errors to {COMPARE_UNTIL} s against h = {ref_h * 1e3:g} mm read projected, "
          f"relative to its peak; observed order of the projected rms error "
          f"{order if order is None else round(order, 2)}; CPU: {cpu})",
          ["h [mm]", "DOFs", "contact nodes", "rms", "max, indent", "max, slide", "rms L-R", "peak",
           "pointwise: rms", "pointwise: rms L-R", "slip [ms]", "ms per sample (every)", "simulate 2 s [ms]",
           "setup [s]"], table_rows)
    os.makedirs(args.out, exist_ok=True)
    env = environment()
    env["cpu_model"] = cpu
    doc = {"environment": env, "scene": "fig6", "compare_until_s": COMPARE_UNTIL, "reference_h_mm": ref_h * 1e3,
           "reference_slip_time_s": ref["slip_time_s"], "default_h_mm": default_h * 1e3, "observed_order": order,
           "quick": bool(args.quick), "repeat": repeat, "seconds": time.perf_counter() - t0,
           "rows": [{k: v for k, v in r.items() if k not in ("stress", "stress_pointwise")} for r in rows]}
    write_json(os.path.join(args.out, "mesh_study.json"), doc, indent=1)
    figure(rows, default_h * 1e3, order, ref_h * 1e3, os.path.join(args.out, "mesh_study.png"))
    print(f"\nWrote {args.out}/mesh_study.json and mesh_study.png ({time.perf_counter() - t0:.0f} s)")
    return rows[-1]["errors"]["rms"]


if __name__ == "__main__":
    main()
