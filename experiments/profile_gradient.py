"""What the gradient of one right-hand side costs, piece by piece, with and without the per-block
rematerialisation of the stencil passes (:func:`mlsph_jax.approximation.block_remat`, ``--ab
remat``) or the scanned-block derivative of the blocked passes
(:func:`mlsph_jax.approximation.block_scan`, ``--ab scan``, the default).  Not a test.

Taylor-Green (``configs/taylor_green_2d.toml``, n x n, Eulerian, geometry fixed).  Pieces:
``mid`` (reconstruction fit and midpoint states, a blocked pass), ``visc`` (viscous fluxes,
unblocked), ``full`` (:func:`mlsph_jax.rhs.rhs`: both plus the blocked flux sweep).  For each,
the forward and ``jax.vjp`` (forward + pullback, w.r.t. the conserved fields) are compiled ahead
of time and timed interleaved (switch on, off, on, off, ...); the figure is the best CPU time of
this process over ``--repeat`` calls (``time.process_time``: on a shared machine it moves less
with the load than wall time; both are printed).  Prints the load average beside every row.

    python experiments/profile_gradient.py [--n 50] [--repeat 7] [--rounds 2] [--ab scan|remat]
        [--pieces mid visc full] [--thunks TOP]

``--thunks TOP`` (instead of the timings): a ``jax.profiler`` trace of one call of each piece's
forward and vjp (defaults: rematerialisation and scanned blocks on), XLA thunk times summed by the
source line of their root operation (``profile_step.thunk_table``), the TOP lines of each.

"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from mlsph_jax import config
from mlsph_jax.approximation import block_remat, block_scan
from mlsph_jax.cases import build_problem
from mlsph_jax.eos import get_eos, to_primitive
from mlsph_jax.rhs import rhs
from mlsph_jax.run import setup_run
from mlsph_jax.viscous import viscous_terms

ROOT = Path(__file__).resolve().parents[1]


def pieces(n: int):
    pb = build_problem(config.load(ROOT / "configs/taylor_green_2d.toml", [f"case.n={n}"]))
    p = pb.particles
    geom = setup_run(pb, headroom=1.6).geometry_fn(p)(p)
    scheme, params = pb.scheme, pb.params
    eos = get_eos(scheme.eos)

    def mid(q):
        F = scheme.component("reconstruction_variables").from_conservative(q / p.vol[:, None], eos, params)
        return scheme.component("reconstruction").midpoint_states(F, geom, scheme.reconstruction_degree)

    def visc(q):
        return viscous_terms(to_primitive(q / p.vol[:, None], eos, params), geom, scheme, params, scheme.fit_degree)

    def full(q):
        return rhs(p.replace(q=q), params, geom, scheme, pb.boundary)[2]

    return p.q, {"mid": mid, "visc": visc, "full": full}


def best(fn, arg, repeat: int) -> tuple[float, float]:
    wall = cpu = float("inf")
    for _ in range(repeat):
        c0, t0 = time.process_time(), time.perf_counter()
        jax.block_until_ready(fn(arg))
        wall, cpu = min(wall, time.perf_counter() - t0), min(cpu, time.process_time() - c0)
    return wall, cpu


def thunks_by_line(q, fns, top: int):
    """Print the thunk times of each piece's forward and vjp summed by source line."""
    import re
    import tempfile
    from collections import Counter

    from profile_step import thunk_table

    for name, f in fns.items():
        y = f(q)
        ct = jnp.cos(0.1 * jnp.arange(y.size, dtype=y.dtype)).reshape(y.shape)
        for kind, prog in (("forward", jax.jit(f)), ("vjp", jax.jit(lambda q, f=f, ct=ct: jax.vjp(f, q)[1](ct)))):
            with tempfile.TemporaryDirectory() as folder:
                rows = thunk_table(prog.lower(q).compile(), (q,), 1, 10**6, folder)
            ms, calls = Counter(), Counter()
            for r in rows:
                m = re.search(r"^(\S+) \(([^()]*:\d+)\)$", r["from"])
                key = f"{m.group(2)} {m.group(1)}" if m else "(no source line)"
                ms[key] += r["ms_per_step"]
                calls[key] += r["calls"]
            print(f"{name} {kind}: {sum(ms.values()):.1f} ms in {sum(calls.values())} thunk calls; "
                  f"load {os.getloadavg()[0]:.1f}")
            for key, v in ms.most_common(top):
                print(f"  {v:8.2f} ms {calls[key]:6d} calls  {key}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=50, help="particles per side")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--ab", choices=("scan", "remat"), default="scan", help="which trace-time switch to compare")
    ap.add_argument("--pieces", nargs="+", choices=("mid", "visc", "full"), default=["mid", "visc", "full"])
    ap.add_argument("--thunks", type=int, default=0, help="print the TOP source lines of a profile instead")
    args = ap.parse_args()
    q, fns = pieces(args.n)
    fns = {k: fns[k] for k in args.pieces}
    if args.thunks:
        thunks_by_line(q, fns, args.thunks)
        return
    switch = {"scan": block_scan, "remat": block_remat}[args.ab]
    progs = {}
    for remat in (True, False):
        for name, f in fns.items():
            y = f(q)
            ct = jnp.cos(0.1 * jnp.arange(y.size, dtype=y.dtype)).reshape(y.shape)
            with switch(remat):
                fwd = jax.jit(f).lower(q).compile()
                vjp = jax.jit(lambda q, f=f, ct=ct: jax.vjp(f, q)[1](ct)).lower(q).compile()
            progs[(name, remat)] = (fwd, vjp)
    print(f"Taylor-Green {args.n}x{args.n}: best of {args.repeat}, CPU ms (wall ms); switch: block {args.ab}")
    for r in range(args.rounds):
        for name in fns:
            for remat in (True, False):
                fwd, vjp = progs[(name, remat)]
                (wf, cf), (wv, cv) = best(fwd, q, args.repeat), best(vjp, q, args.repeat)
                print(f"round {r} {name:5s} block {args.ab} {'on ' if remat else 'off'}: forward {cf * 1e3:7.2f} "
                      f"({wf * 1e3:7.2f})  vjp {cv * 1e3:7.2f} ({wv * 1e3:7.2f})  vjp/forward {cv / cf:5.2f}  "
                      f"load {os.getloadavg()[0]:.1f}", flush=True)


if __name__ == "__main__":
    main()
