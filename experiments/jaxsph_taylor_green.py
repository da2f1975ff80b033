"""Run JAX-SPH (the ``jax-sph`` package, installed) on the Taylor-Green vortex of
``bench_scale.py`` and print its throughput.  Runs with the interpreter of the environment
``bench_scale.py`` creates (``experiments/output/.venv_jaxsph``), never with this project's.

Only the installed package's public entry points are used: ``jax_sph.defaults.set_defaults``
for the configuration, a case class written here (a subclass of
``jax_sph.case_setup.SimulationSetup``, loaded by the package from a file as its own cases are)
and ``jax_sph.simulate.simulate``, which runs the solver and prints its loop time.

The vortex: unit periodic square, u = U0 (sin kx cos ky, -cos kx sin ky), k = 2 pi, U0 = 1,
rho0 = 1, viscosity 0.01 (Re = 100), c0 = 10 U0, n x n particles on the Cartesian lattice,
weakly compressible SPH with the transport-velocity formulation (``solver.tvf = 1``), float64,
JAX-SPH's own time step (0.25 dx / (c0 + U0)).

    <venv>/bin/python experiments/jaxsph_taylor_green.py --n 50 --steps 50

Prints ``RESULT{json}``: particles, steps, dt, loop seconds, particle-steps/s, set-up+compile s.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import tempfile
import time
from pathlib import Path

CASE = '''
import jax.numpy as jnp
import numpy as np
from jax_sph.case_setup import SimulationSetup


class TGV_BENCH(SimulationSetup):
    """Taylor-Green vortex on the unit periodic square (no walls, no body force)."""

    def _box_size2D(self, n_walls):
        return np.array([1.0, 1.0])

    def _box_size3D(self, n_walls):
        return np.array([1.0, 1.0, 1.0])

    def _init_walls_2d(self):
        pass

    def _init_walls_3d(self):
        pass

    def _init_velocity2D(self, r):
        k = 2.0 * jnp.pi
        return jnp.array([jnp.sin(k * r[0]) * jnp.cos(k * r[1]), -jnp.cos(k * r[0]) * jnp.sin(k * r[1])])

    def _init_velocity3D(self, r):
        return jnp.zeros_like(r)

    def _external_acceleration_fn(self, r):
        return jnp.zeros_like(r)

    def _boundary_conditions_fn(self, state):
        return state
'''


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=50)
    ap.add_argument("--steps", type=int, default=50)
    a = ap.parse_args()

    import jax

    jax.config.update("jax_enable_x64", True)
    from jax_sph.defaults import set_defaults
    from jax_sph.simulate import simulate

    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "tgv_bench.py").write_text(CASE)
        cfg = set_defaults()
        cfg.config = str(Path(tmp) / "tgv_bench.yaml")  # the package reads the case folder from it
        cfg.case.source = "tgv_bench.py"
        cfg.case.dim = 2
        cfg.case.dx = 1.0 / a.n
        cfg.case.viscosity = 0.01
        cfg.case.u_ref = 1.0
        cfg.case.c_ref_factor = 10.0
        cfg.case.rho_ref = 1.0
        cfg.solver.name = "SPH"
        cfg.solver.tvf = 1.0
        cfg.eos.p_bg_factor = 0.0
        dt = cfg.solver.cfl * cfg.case.dx / (cfg.case.c_ref_factor * cfg.case.u_ref + cfg.case.u_ref)
        # simulate() runs int(t_end / dt) + 2 steps
        cfg.solver.t_end = (a.steps - 2 + 0.5) * dt
        cfg.io.data_path = tmp
        cfg.io.write_type = []
        cfg.io.write_every = 10 ** 9
        cfg.io.print_props = ["Ekin"]
        buf = io.StringIO()
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(buf):
            simulate(cfg)
        total = time.perf_counter() - t0
    text = buf.getvalue()
    loop = float(re.findall(r"^time: ([0-9.eE+-]+) s", text, re.M)[-1])
    n_part = int(re.findall(r"Total number of particles =\s+(\d+)", text)[-1])
    steps = int(cfg.solver.sequence_length) + 2
    print("RESULT" + json.dumps({"particles": n_part, "steps": steps, "dt": float(cfg.solver.dt),
                                 "loop_s": loop, "particle_steps_per_s": n_part * steps / loop,
                                 "compile_s": total - loop, "jax": jax.__version__, "precision": "float64"}))


if __name__ == "__main__":
    main()
