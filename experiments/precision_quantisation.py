"""Why float32 Taylor-Green pressures differ from float64: the density quantisation eps32 rho0 c0^2.

For c0 in ``--c0`` and each low-Mach option in ``--low-mach``, runs the reduced Taylor-Green
(``mlsph_jax.testing.REDUCED_OVERRIDES``: 12 x 12, t = 0.05) in float64 and float32
(``run.precision``) and prints the absolute float32 - float64 differences of the error metrics
next to the bound B_p = 2 eps32 (c0/U0)^2 / F^2 (pressure metric, units rho0 U0^2 F^2 / 2) and
the conserved-state differences per component (relative to each component's scale).  Writes
``experiments/output/precision_quantisation.json``.  docs/performance.md (Precision) quotes it.

    python experiments/precision_quantisation.py --c0 10 20 40 --low-mach none thornber
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib

import numpy as np

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.simulation import run_problem
from mlsph_jax.testing import CONFIG_DIR, REDUCED_OVERRIDES

METRICS = ("l2_pressure_error", "l2_velocity_error", "ke_rel_error")


def pair(overrides):
    out = {}
    for prec in ("float64", "float32"):
        cfg = config.load(CONFIG_DIR / "taylor_green_2d.toml",
                          [*overrides, f"run.precision={prec}", "output.plots=false", "output.progress=false"])
        out[prec] = run_problem(build_problem(cfg), cfg, quiet=True)
    return cfg, out["float64"], out["float32"]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--c0", type=float, nargs="+", default=[10.0, 20.0, 40.0])
    ap.add_argument("--low-mach", nargs="+", default=["none", "thornber"])
    ap.add_argument("--out", type=pathlib.Path,
                    default=pathlib.Path(__file__).parent / "output" / "precision_quantisation.json")
    a = ap.parse_args(argv)
    rows = []
    for c0 in a.c0:
        for lm in a.low_mach:
            cfg, r64, r32 = pair((*REDUCED_OVERRIDES["taylor_green_2d"], f"eos.c0={c0!r}",
                                  f"scheme.low_mach_reconstruction={lm}"))
            t, u0, length = r64.summary["t_final"], float(cfg["case"]["u0"]), float(cfg["case"]["length"])
            nu = u0 * length / float(cfg["case"]["re"])
            b_p = 2.0 * np.finfo(np.float32).eps * (c0 / u0) ** 2 / np.exp(-4.0 * (2 * np.pi / length) ** 2 * nu * t)
            q64, q32 = np.asarray(r64.particles.q), np.asarray(r32.particles.q, np.float64)
            dq = (np.abs(q64 - q32).max(0) / np.abs(q64).max(0)).tolist()
            m64, m32 = r64.summary["metrics"], r32.summary["metrics"]
            row = {"c0": c0, "low_mach": lm, "bound_pressure": b_p, "state_difference": dq,
                   **{k: m64[k] for k in METRICS}, **{f"{k}_abs_difference": abs(m32[k] - m64[k]) for k in METRICS}}
            rows.append(row)
            print(f"c0={c0:5.1f} {lm:9s} B_p={b_p:.2e}  " + "  ".join(
                f"{k}={m64[k]:.3e} |d|={row[k + '_abs_difference']:.1e}" for k in METRICS)
                + "  dq/scale=" + " ".join(f"{d:.1e}" for d in dq), flush=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({"rows": rows, "load_average": os.getloadavg()}, indent=1) + "\n")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
