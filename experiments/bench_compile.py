"""Compile time of every built-in config at its shipped size (issue 15: "compile time <= 20 s for
every built-in config"), with the size of the compiled program and the stepping speed beside it.

Per config, as ``mlsph run`` does it (``simulation.make_simulation``): the Eulerian geometry (first
call of the jitted ``static_geometry``: its compilation plus one evaluation; moving frames have
none), then the run's chunk lowered and compiled ahead of time (``jit(...).lower(...).compile()``,
the figure ``summary.json`` reports as ``compile_time_s``), then ``--steps`` steps of the compiled
chunk timed twice (the best is kept; particle-updates/s).  Also reported: XLA's backend
compilation time summed over every program the config compiled (``jax.monitoring``), and the
instruction count of the optimised HLO of the chunk (what compile time grows with).

    python experiments/bench_compile.py [--only NAME ...] [--steps 5] [--out FILE]

Prints one row per config with the load average and writes experiments/output/bench_compile.json
(``--out`` to change).  Compare two versions interleaved (one config at a time, alternating the
checkouts via PYTHONPATH) so that machine load hits both alike.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.integrate import initial_carry
from mlsph_jax.simulation import make_simulation
from mlsph_jax.testing import builtin_configs

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "output" / "bench_compile.json"
_BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"
_HLO_INSTRUCTION = re.compile(r"^\s*(ROOT\s+)?%?[\w.\-]+ = ", re.M)


class _CompileClock:
    """Sum of XLA backend compilation durations reported by ``jax.monitoring``."""

    def __init__(self):
        self.total = 0.0
        jax.monitoring.register_event_duration_secs_listener(self._record)

    def _record(self, event, duration, **_):
        if event == _BACKEND_COMPILE:
            self.total += duration


def bench_config(name: str, steps: int, clock: _CompileClock) -> dict:
    cfg = config.load(ROOT / "configs" / f"{name}.toml", ["output.plots=false", "output.progress=false"])
    pb = build_problem(cfg)
    sim = make_simulation(pb, cfg)
    p0, params = sim.problem.particles, sim.problem.params
    carry = initial_carry(p0)
    backend0 = clock.total
    t0 = time.perf_counter()
    _, geom = sim.setup.host_geometry(p0)
    jax.block_until_ready(geom)
    geometry_s = time.perf_counter() - t0
    chunk = sim.setup.make_chunk(sim.control, sim.chunk_steps)
    t_stop = jnp.asarray(pb.t_end)
    t0 = time.perf_counter()
    lowered = chunk.lower(carry, params, geom, t_stop, jnp.asarray(steps, jnp.int32))
    lower_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    compiled = lowered.compile()
    compile_s = time.perf_counter() - t0
    backend_s = clock.total - backend0
    hlo_ops = len(_HLO_INSTRUCTION.findall(compiled.as_text()))
    best = float("inf")
    for _ in range(2):   # steps 0..steps-1 from the initial state, twice (same work)
        t0 = time.perf_counter()
        out = compiled(carry, params, geom, t_stop, jnp.asarray(steps, jnp.int32))
        int(out.status)
        best = min(best, time.perf_counter() - t0)
    done = int(out.step)
    return {"config": name, "n_particles": int(p0.n), "geometry_first_call_s": geometry_s,
            "chunk_lower_s": lower_s, "chunk_compile_s": compile_s, "chunk_total_s": lower_s + compile_s,
            "backend_compile_all_s": backend_s, "chunk_hlo_instructions": hlo_ops, "steps": done,
            "step_s": best / max(done, 1), "particle_updates_per_s": int(p0.n) * done / best,
            "status": int(out.status), "load_avg": os.getloadavg()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="+", default=None, help="config stems (default: all built-in configs)")
    ap.add_argument("--steps", type=int, default=5, help="steps per timed call of the compiled chunk")
    ap.add_argument("--out", default=str(OUT))
    args = ap.parse_args(argv)
    clock = _CompileClock()
    rows = []
    print(f"{'config':24s} {'N':>6s} {'geom s':>7s} {'lower s':>7s} {'compile s':>9s} {'XLA all s':>9s} "
          f"{'HLO instr':>9s} {'upd/s':>9s}  load", flush=True)
    for name in args.only or builtin_configs():
        r = bench_config(name, args.steps, clock)
        rows.append(r)
        print(f"{name:24s} {r['n_particles']:6d} {r['geometry_first_call_s']:7.2f} {r['chunk_lower_s']:7.2f} "
              f"{r['chunk_compile_s']:9.2f} {r['backend_compile_all_s']:9.2f} {r['chunk_hlo_instructions']:9d} "
              f"{r['particle_updates_per_s']:9.3g}  {r['load_avg'][0]:.2f}", flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"jax": jax.__version__, "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
