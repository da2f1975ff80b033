"""Throughput of the semi-discrete right-hand side (:mod:`mlsph_jax.rhs`).

Layout: jittered Cartesian lattice (jitter +-0.1 dx) in the periodic unit square (``--dim 3``:
cube), uniform volumes dx^d, ideal gas (gamma = 1.4) with a smooth non-uniform state (density, velocity and
pressure waves).  Schemes (Eulerian frame by default):

* ``mlsph_ale`` degree 2 and 3 (full MLS derivative, reconstruction degree = degree, beta 1.5);
* ``sph_ale`` (kernel areas, beta 2, Taylor reconstruction of degree 2);

each with every numerical flux of ``--flux`` (default ``rusanov``; e.g. ``--flux rusanov hllc
hllc_lm hllc_zha``; ``hllc_lm`` gets ``scheme.reference_mach`` from ``--reference-mach``) and every
low-Mach reconstruction of ``--low-mach`` (default ``none``; e.g. ``--low-mach none thornber``).

For every scheme and size the neighbour list is built once (not timed), sized as the driver
sizes it (:func:`mlsph_jax.run.plan_neighbors`, ``scheme.neighbor_headroom`` 1.3: Eulerian
particles get their largest count as capacity since decision 91, moving ones the headroom); then

* ``rhs``:       ``rhs(particles, params, geom, scheme)`` with a precomputed Geometry (what an
  Eulerian run evaluates per Runge-Kutta stage);
* ``geom+rhs``:  ``geometry(...)`` followed by ``rhs(...)`` (what a moving-particle run evaluates
  per stage, neighbour search excluded);

each compiled ahead of time (``jax.jit(f).lower(...).compile()``, compile time reported
separately) and timed as the median of ``--repeat`` runs.  Throughput is given as
right-hand-side evaluations per second and particle updates per second (N / time); for every
flux variant after the first of a scheme and size, the cost ratio of its ``rhs`` time to the
first one's.  Writes ``experiments/output/bench_rhs.json``.  Not a test.

Usage::

    python experiments/bench_rhs.py --sizes 10000 40000 160000 --repeat 5
    python experiments/bench_rhs.py --sizes 40000 --schemes mlsph_ale-2 --flux rusanov hllc hllc_lm hllc_zha \
        --low-mach none thornber
    python experiments/bench_rhs.py --sizes 40000 --schemes mlsph_ale-2 --baseline 28afe3f --rounds 9
    MALLOC_MMAP_MAX_=0 MALLOC_TRIM_THRESHOLD_=1000000000000000 MALLOC_TOP_PAD_=67108864 \
        python experiments/bench_rhs.py --sizes 40000 --schemes mlsph_ale-2 --repeat 25

Every row records the minor page faults of one more ``rhs`` call (``rhs_minor_faults_per_call``:
XLA:CPU maps the temporaries of each execution afresh) and the JSON's meta the peak resident
memory and the glibc ``MALLOC_*`` environment variables in effect (docs/performance.md, "Page
faults of a bare call").

``--baseline REF``: this tree's ``rhs`` against that of the git ref (exported and imported as a
second package, as in bench_moving_frames.py), both compiled in one process and called in turn
(A B A B ...): wall and process CPU time (best and median), the load average before and after,
and the largest difference of d(VU)/dt (0 when a change keeps the numbers); writes
``experiments/output/bench_rhs_ab.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

try:   # Unix only: page faults and peak memory are then not recorded
    import resource
except ImportError:   # pragma: no cover
    resource = None

import mlsph_jax
from mlsph_jax.eos import get_eos, to_conservative
from mlsph_jax.rhs import geometry, rhs
from mlsph_jax.run import plan_neighbors
from mlsph_jax.scheme import Scheme
from mlsph_jax.state import Domain, Params, make_particles

SCHEMES = {
    "mlsph_ale-2": dict(method="mlsph_ale", degree=2, reconstruction_degree=2, beta=1.5),
    "mlsph_ale-3": dict(method="mlsph_ale", degree=3, reconstruction_degree=3, beta=1.5),
    "sph_ale-2": dict(method="sph_ale", degree=2, reconstruction_degree=2, beta=2.0),
}


def layout(n_target: int, rng: np.random.Generator, jitter: float = 0.1, dim: int = 2):
    """Jittered Cartesian lattice of about ``n_target`` particles in the periodic unit square/cube."""
    m = max(4, round(n_target ** (1.0 / dim)))
    dx = 1.0 / m
    ax = (np.arange(m) + 0.5) * dx
    x = np.stack(np.meshgrid(*([ax] * dim), indexing="ij"), axis=-1).reshape(-1, dim)
    x = np.mod(x + rng.uniform(-jitter, jitter, x.shape) * dx, 1.0)
    return x, dx


def smooth_state(x, params):
    """Smooth non-uniform ideal-gas state: conservative U[N, d + 2]."""
    k = 2.0 * np.pi
    rho = 1.0 + 0.2 * np.sin(k * x[:, 0]) * np.cos(k * x[:, 1])
    comps = [0.3 * np.sin(k * x[:, 1]), 0.2 * np.cos(k * x[:, 0])]
    if x.shape[1] == 3:
        comps.append(0.1 * np.sin(k * (x[:, 0] + x[:, 2])))
    vel = np.stack(comps, axis=-1)
    p = 1.0 + 0.1 * np.cos(k * (x[:, 0] + x[:, 1]))
    return np.asarray(
        to_conservative(
            jnp.asarray(rho), jnp.asarray(vel), jnp.asarray(p), get_eos("ideal_gas"), params
        )
    )


def _time(fn, args, repeat: int):
    jax.block_until_ready(fn(*args))  # warm-up
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)), float(np.min(ts))


def run(name: str, n_target: int, repeat: int, frame: str, seed: int, flux: str = "rusanov",
        low_mach: str = "none", reference_mach: float = 0.1, keep: list | None = None, dim: int = 2) -> dict:
    from mlsph_jax.flux import FLUXES

    mref = reference_mach if getattr(FLUXES.get(flux, "--flux"), "uses_reference_mach", False) else 0.0
    scheme = Scheme(**SCHEMES[name], frame=frame, flux=flux, low_mach_reconstruction=low_mach, reference_mach=mref)
    rng = np.random.default_rng(seed)
    x, dx = layout(n_target, rng, dim=dim)
    n = x.shape[0]
    params = Params({"eos.gamma": 1.4})
    vol = np.full(n, dx**dim)
    particles = make_particles(x, vol, smooth_state(x, params))
    domain = Domain((0.0,) * dim, (1.0,) * dim, (True,) * dim)
    _, nl = plan_neighbors(particles, scheme, domain, headroom=1.3, min_moving_headroom=True)
    assert not bool(nl.overflow)

    def geom_fn(p, nl):
        return geometry(p.x, p.vol, nl, scheme, domain)

    def rhs_fn(p, prm, g):
        return rhs(p, prm, g, scheme)

    def full_fn(p, prm, nl):
        return rhs(p, prm, geometry(p.x, p.vol, nl, scheme, domain), scheme)

    out = dict(
        scheme=name,
        flux=flux,
        low_mach_reconstruction=low_mach,
        reference_mach=mref,
        method=scheme.method,
        degree=scheme.degree,
        reconstruction_degree=scheme.reconstruction_degree,
        beta=scheme.beta,
        frame=frame,
        dim=dim,
        n=n,
        capacity=int(nl.idx.shape[1]),
        mean_neighbors=float(np.mean(nl.count)),
    )
    t0 = time.perf_counter()
    geom_c = jax.jit(geom_fn).lower(particles, nl).compile()
    out["compile_geometry_s"] = time.perf_counter() - t0
    geom = jax.block_until_ready(geom_c(particles, nl))
    t0 = time.perf_counter()
    rhs_c = jax.jit(rhs_fn).lower(particles, params, geom).compile()
    out["compile_rhs_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    full_c = jax.jit(full_fn).lower(particles, params, nl).compile()
    out["compile_geom_rhs_s"] = time.perf_counter() - t0

    out["geometry_s"], out["geometry_min_s"] = _time(geom_c, (particles, nl), repeat)
    out["rhs_s"], out["rhs_min_s"] = _time(rhs_c, (particles, params, geom), repeat)
    out["geom_rhs_s"], out["geom_rhs_min_s"] = _time(full_c, (particles, params, nl), repeat)
    for k in ("geometry", "rhs", "geom_rhs"):
        out[f"{k}_evals_per_s"] = 1.0 / out[f"{k}_s"]
        out[f"{k}_particles_per_s"] = n / out[f"{k}_s"]
    # page faults of one more call: XLA:CPU maps each execution's temporaries afresh (decision 115)
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt if resource else 0
    jax.block_until_ready(rhs_c(particles, params, geom))
    out["rhs_minor_faults_per_call"] = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) if resource else None
    dq = np.asarray(rhs_c(particles, params, geom)[2])
    out["checksum_dq_abs"] = float(np.abs(dq).sum())
    if keep is not None:      # the compiled rhs and its arguments, for the interleaved timing
        keep.append((rhs_c, (particles, params, geom)))
    return out


def interleaved_min(calls, rounds: int) -> list[float]:
    """Minimum time of each compiled call over ``rounds`` rounds that call them in turn (A B C A B
    C ...): on a shared machine, load changes hit every variant alike, and the minimum is the
    least disturbed run."""
    best = [float("inf")] * len(calls)
    for _ in range(rounds):
        for i, (fn, a) in enumerate(calls):
            t0 = time.perf_counter()
            jax.block_until_ready(fn(*a))
            best[i] = min(best[i], time.perf_counter() - t0)
    return best


def baseline_rhs(pkg, name: str, n_target: int, seed: int, frame: str, dim: int = 2):
    """``(compiled rhs, args, N, K)`` of the bench's ``name`` scheme built with ``pkg`` (this
    package or a baseline copy of it, :func:`bench_moving_frames.baseline_package`)."""
    import importlib

    mod = {m: importlib.import_module(f"{pkg.__name__}.{m}") for m in ("run", "rhs", "scheme", "state", "eos")}
    scheme = mod["scheme"].Scheme(**SCHEMES[name], frame=frame)
    x, dx = layout(n_target, np.random.default_rng(seed), dim=dim)
    n = x.shape[0]
    params = mod["state"].Params({"eos.gamma": 1.4})
    vol = np.full(n, dx**dim)
    particles = mod["state"].make_particles(x, vol, smooth_state(x, params))
    domain = mod["state"].Domain((0.0,) * dim, (1.0,) * dim, (True,) * dim)
    _, nl = mod["run"].plan_neighbors(particles, scheme, domain, headroom=1.3, min_moving_headroom=True)
    geom = jax.jit(lambda p, nl: mod["rhs"].geometry(p.x, p.vol, nl, scheme, domain))(particles, nl)
    c = jax.jit(lambda p, prm, g: mod["rhs"].rhs(p, prm, g, scheme)).lower(particles, params, geom).compile()
    return c, (particles, params, geom), n, int(nl.idx.shape[1])


def ab_rounds(baseline: str, name: str, n_target: int, rounds: int, seed: int, frame: str, dim: int) -> dict:
    """This tree's rhs against ``baseline``'s (a git ref), compiled in one process and called in
    turn (base, this, base, this, ...) ``rounds`` times: best and median wall time and process CPU
    time of each, the load average before and after, and max |d(VU)/dt this - base|."""
    import os
    import sys
    import tempfile

    sys.path.insert(0, str(pathlib.Path(__file__).parent))
    from bench_moving_frames import baseline_package

    tmp = tempfile.TemporaryDirectory()
    calls = {"base": baseline_rhs(baseline_package(baseline, tmp.name), name, n_target, seed, frame, dim),
             "this": baseline_rhs(mlsph_jax, name, n_target, seed, frame, dim)}
    out = {k: np.asarray(c(*a)[2]) for k, (c, a, _, _) in calls.items()}
    load0 = os.getloadavg()
    wall = {k: [] for k in calls}
    cpu = {k: [] for k in calls}
    for _ in range(rounds):
        for k, (c, a, _, _) in calls.items():
            w0, c0 = time.perf_counter(), time.process_time()
            jax.block_until_ready(c(*a))
            wall[k].append(time.perf_counter() - w0)
            cpu[k].append(time.process_time() - c0)
    load1 = os.getloadavg()
    n, cap = calls["this"][2], calls["this"][3]
    res = dict(baseline=baseline, scheme=name, n=n, capacity=cap, base_capacity=calls["base"][3],
               rounds=rounds, load_average=[load0, load1],
               max_abs_diff_dq=float(np.max(np.abs(out["this"] - out["base"]))))
    for k in calls:
        res[k] = dict(wall_best_s=min(wall[k]), wall_median_s=float(np.median(wall[k])),
                      cpu_best_s=min(cpu[k]), cpu_median_s=float(np.median(cpu[k])),
                      particles_per_s_best=n / min(wall[k]))
    return res


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[10_000, 40_000, 160_000])
    p.add_argument("--schemes", nargs="+", default=list(SCHEMES), choices=list(SCHEMES))
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--frame", default="eulerian", choices=["eulerian", "lagrangian"])
    p.add_argument("--flux", nargs="+", default=["rusanov"], help="registered fluxes (scheme.flux) to time")
    p.add_argument("--low-mach", nargs="+", default=["none"],
                   help="low-Mach reconstructions (scheme.low_mach_reconstruction) to time")
    p.add_argument("--interleave", type=int, default=0,
                   help="after the variants of a scheme and size, time their rhs in N interleaved rounds "
                        "(minimum; robust cost ratios on a loaded machine); 0 = off")
    p.add_argument("--reference-mach", type=float, default=0.1,
                   help="scheme.reference_mach for the fluxes that need one (hllc_lm)")
    p.add_argument("--dim", type=int, default=2, choices=[2, 3], help="2D square or 3D cube (N = n^dim)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--baseline", default=None,
                   help="git ref: instead of the table, this tree's rhs against the ref's, interleaved in one "
                        "process (--rounds rounds; wall and process CPU time, load average)")
    p.add_argument("--rounds", type=int, default=7, help="interleaved rounds of --baseline")
    p.add_argument(
        "--out",
        type=pathlib.Path,
        default=pathlib.Path(__file__).parent / "output" / "bench_rhs.json",
    )
    args = p.parse_args(argv)
    if args.baseline:
        rows = []
        for name in args.schemes:
            for n in args.sizes:
                r = ab_rounds(args.baseline, name, n, args.rounds, args.seed, args.frame, args.dim)
                rows.append(r)
                (l0, l1) = r["load_average"]
                for k in ("base", "this"):
                    v = r[k]
                    cap = r["base_capacity" if k == "base" else "capacity"]
                    print(f"{name} N={r['n']} K={cap} {k:>4s}: wall best {1e3 * v['wall_best_s']:7.1f} ms "
                          f"(median {1e3 * v['wall_median_s']:7.1f}), CPU best {1e3 * v['cpu_best_s']:7.1f} ms "
                          f"(median {1e3 * v['cpu_median_s']:7.1f}), {v['particles_per_s_best']:.3e} particle "
                          "evaluations/s", flush=True)
                print(f"  this / base: wall {r['this']['wall_best_s'] / r['base']['wall_best_s']:.3f} (best), "
                      f"{r['this']['wall_median_s'] / r['base']['wall_median_s']:.3f} (median); CPU "
                      f"{r['this']['cpu_best_s'] / r['base']['cpu_best_s']:.3f} (best); max |dq - base| "
                      f"{r['max_abs_diff_dq']:.1e}; load average {l0[0]:.2f} -> {l1[0]:.2f}", flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.with_name("bench_rhs_ab.json").write_text(json.dumps(rows, indent=2))
        return

    hdr = (
        f"{'scheme':<12} {'flux':<18} {'N':>7} {'K':>3} {'comp g/r/gr s':>15} {'rhs s':>8} {'rhs p/s':>9} "
        f"{'ratio':>6} {'geom s':>8} {'g+r s':>8} {'g+r p/s':>9} {'g+r eval/s':>10}"
    )
    print(hdr)
    print("-" * len(hdr))
    rows = []
    variants = [(f, lm) for f in args.flux for lm in args.low_mach]
    for name in args.schemes:
        for n in args.sizes:
            first, keep, group = None, ([] if args.interleave else None), []
            for flux, lm in variants:
                r = run(name, n, args.repeat, args.frame, args.seed, flux, lm, args.reference_mach, keep, args.dim)
                group.append(r)
                first = first or r
                r["rhs_cost_ratio"] = r["rhs_s"] / first["rhs_s"]
                r["ratio_to"] = f"{first['flux']}+{first['low_mach_reconstruction']}"
                rows.append(r)
                comp = "/".join(
                    f"{r[k]:.1f}" for k in ("compile_geometry_s", "compile_rhs_s", "compile_geom_rhs_s")
                )
                label = flux if lm == "none" else f"{flux}+{lm}"
                print(
                    f"{name:<12} {label:<18} {r['n']:>7} {r['capacity']:>3} {comp:>15} {r['rhs_s']:>8.4f} "
                    f"{r['rhs_particles_per_s']:>9.3e} {r['rhs_cost_ratio']:>6.3f} {r['geometry_s']:>8.4f} "
                    f"{r['geom_rhs_s']:>8.4f} "
                    f"{r['geom_rhs_particles_per_s']:>9.3e} {r['geom_rhs_evals_per_s']:>10.2f}",
                    flush=True,
                )
            if args.interleave:
                best = interleaved_min(keep, args.interleave)
                for r, b in zip(group, best, strict=True):
                    r["rhs_interleaved_min_s"] = b
                    r["rhs_interleaved_ratio"] = b / best[0]
                labels = [r["flux"] + ("" if r["low_mach_reconstruction"] == "none"
                                       else "+" + r["low_mach_reconstruction"]) for r in group]
                print(f"  interleaved minimum of {args.interleave} rounds (rhs s, ratio to the first): "
                      + ", ".join(f"{lab} {b:.4f} {b / best[0]:.3f}" for lab, b in zip(labels, best, strict=True)),
                      flush=True)
                del keep
    meta = dict(
        jax=jax.__version__,
        mlsph_jax=mlsph_jax.__version__,
        backend=jax.default_backend(),
        devices=[str(d) for d in jax.devices()],
        platform=platform.platform(),
        processor=platform.processor(),
        repeat=args.repeat,
        frame=args.frame,
        dtype=str(jnp.zeros(()).dtype),
        dim=args.dim,
        interleave=args.interleave,
        malloc_environment={k: v for k, v in os.environ.items() if k.startswith("MALLOC_")},
        peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 if resource else None,   # Linux: KiB
    )
    if resource:
        print(f"minor page faults per rhs call: {', '.join(str(r['rhs_minor_faults_per_call']) for r in rows)}; "
              f"peak RSS {meta['peak_rss_mb']:.0f} MB; "
              f"glibc malloc settings: {meta['malloc_environment'] or 'defaults'}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(dict(meta=meta, results=rows), indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
