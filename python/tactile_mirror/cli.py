"""The ``tactile-mirror`` command."""
from __future__ import annotations

import argparse
import sys


def _demo(args: argparse.Namespace) -> int:
    import numpy as np
    import scipy.signal

    from . import SosFilter, simd_path, sosfilt

    fs = 10_000.0
    sos = scipy.signal.butter(4, 0.5, "highpass", fs=fs, output="sos")
    rng = np.random.default_rng(args.seed)
    x = rng.standard_normal((12, 100_000))
    ref = scipy.signal.sosfilt(sos, x)
    y64 = sosfilt(sos, x)
    f32 = SosFilter(sos, channels=12, dtype=np.float32)
    y32 = f32.process(x.astype(np.float32))
    peak = np.max(np.abs(ref))
    print(f"SIMD path: {simd_path()}")
    print(f"float64 sosfilt vs scipy: max |error| / peak = {np.max(np.abs(y64 - ref)) / peak:.2e}")
    print(f"float32 SosFilter ({f32.structure[0]}) vs float64 scipy: "
          f"max |error| / peak = {np.max(np.abs(y32 - ref)) / peak:.2e}")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="tactile-mirror", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("demo", help="run the demo on the bundled defaults")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.set_defaults(func=_demo)
    args = parser.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
