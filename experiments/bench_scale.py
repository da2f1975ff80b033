"""Scaling of the Taylor-Green step: particle-steps/s against N (2D and 3D), against the device
count, compile time, memory per particle, and JAX-SPH side by side on the same vortex.

* **N sweep.**  ``taylor_green_2d`` (L = 1, Re = 100, Cartesian lattice, MLSPH-ALE, quadratic
  MLS reconstruction, Eulerian frame by default) on n x n particles for n in ``--sizes2d``, and
  its 3D analogue on n^3 particles for n in ``--sizes3d`` (periodic unit cube, u = U0 (sin kx cos
  ky cos kz, -cos kx sin ky cos kz, 0), rho = rho0; the same scheme and EOS; a cost benchmark,
  no exact solution).  A fixed step dt = 0.3 dx / (c0 + U0) (or the viscous limit where it
  binds, n > 330) and ``--steps`` steps in one jitted chunk; compile time (lowering + XLA
  compilation of the chunk) and stepping time (the compiled chunk's execution,
  ``summary["chunk_time_s"]``) are separate.
  The cost exponent is the least-squares slope of log(seconds per step) against log N; with
  ``--rounds R`` each size runs R times and the slope of log(CPU seconds per step) is reported
  too (robust to the contention of a shared machine).
  Memory per particle is XLA's memory analysis of the compiled chunk (arguments + outputs +
  temporaries, per device) divided by N.
* **Devices.**  For each N in ``--device-sizes`` a subprocess with
  ``XLA_FLAGS=--xla_force_host_platform_device_count=2`` runs the same case with
  ``run.devices`` = 1 and 2 (:mod:`mlsph_jax.sharding`); the speed-up is their ratio.
* **Precision.**  For each n in ``--precision-sizes`` the 2D case with ``run.precision`` =
  float64 and float32: the speed-up, the largest difference of the conserved quantities
  relative to their scale, and the L2 velocity error of each against the exact vortex.
* **JAX-SPH** (Toshev et al. 2024, the ``jax-sph`` package from the registry): the script
  creates ``experiments/output/.venv_jaxsph``, pip-installs ``jax-sph`` there (its release
  declares Python <= 3.11.0, so ``--ignore-requires-python --no-deps``, then its declared
  requirements with pip's usual checks) and runs
  ``experiments/jaxsph_taylor_green.py`` with that interpreter, which drives the installed
  package's API (its weakly compressible SPH solver, transport-velocity formulation, float64)
  on the same vortex (unit periodic square, Re = 100, c0 = 10 U0, n x n particles).  When the
  installation fails the comparison is skipped with a message.  Particle-steps/s compares
  steps of different schemes: one of ours holds three right-hand-side evaluations (SSP-RK3),
  one of JAX-SPH's one.

    python experiments/bench_scale.py --quick          # a few minutes
    python experiments/bench_scale.py                  # larger N (minutes)
    python experiments/bench_scale.py --no-jaxsph --sizes2d 32 64 128 256 --sizes3d 10 16 20

Prints one line per run and writes experiments/output/bench_scale.json (not committed).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

from bench_taylor_green import BASE  # the same Taylor-Green config (this folder is on sys.path)

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "output"
VENV = OUT / ".venv_jaxsph"
JAXSPH_DRIVER = ROOT / "experiments" / "jaxsph_taylor_green.py"

CFL = 0.3
MU = 0.01  # the Taylor-Green config's viscosity (Re = 100 on L = 1)


def _fixed_dt(n: int) -> float:
    """The fixed step: the acoustic CFL dt = 0.3 dx / (c0 + U0), and below the viscous limit
    0.125 rho dx^2 / mu of :func:`mlsph_jax.integrate.particle_limits` (at 0.12: it binds from
    n ~ 330 on, where the run would otherwise stop in step 1)."""
    dx = 1.0 / n
    return min(CFL * dx / (10.0 + 1.0), 0.12 * dx * dx / MU)


def _problem_2d(n: int, frame: str, steps: int):
    from mlsph_jax import config
    from mlsph_jax.cases import build_problem

    dt = _fixed_dt(n)
    cfg = config.loads(BASE, [f"case.n={n}", f"scheme.frame={frame}", f"time.t_end={steps * dt * (1 - 1e-9)!r}",
                              f"time.dt={dt!r}", f"run.max_particles={max(2 * n * n, 200_000)}"])
    return build_problem(cfg), cfg, dt


def _problem_3d(n: int, frame: str, steps: int):
    """The 3D periodic vortex on n^3 particles with the scheme and EOS of the 2D config."""
    import jax.numpy as jnp
    import numpy as np

    from mlsph_jax import config
    from mlsph_jax.cases.common import params_from_config, scheme_from_config
    from mlsph_jax.eos import get_eos, to_conservative
    from mlsph_jax.simulation import Problem
    from mlsph_jax.state import Domain, make_particles

    dt = _fixed_dt(n)
    cfg = config.loads(BASE, ["case.n=8", f"scheme.frame={frame}", f"time.t_end={steps * dt * (1 - 1e-9)!r}",
                              f"time.dt={dt!r}", "physics.mu=0.01"])
    scheme, params = scheme_from_config(cfg), params_from_config(cfg)
    dx = 1.0 / n
    g = (np.arange(n) + 0.5) * dx
    x = np.stack([a.ravel() for a in np.meshgrid(g, g, g, indexing="ij")], axis=1)
    k = 2.0 * math.pi
    u = np.stack([np.sin(k * x[:, 0]) * np.cos(k * x[:, 1]) * np.cos(k * x[:, 2]),
                  -np.cos(k * x[:, 0]) * np.sin(k * x[:, 1]) * np.cos(k * x[:, 2]), 0.0 * x[:, 0]], axis=1)
    rho = np.full(len(x), float(cfg["eos"]["rho0"]))
    U = to_conservative(jnp.asarray(rho), jnp.asarray(u), None, get_eos(scheme.eos), params)
    p = make_particles(x, np.full(len(x), dx ** 3), U, ppd=np.full(len(x), scheme.reconstruction_degree))
    pb = Problem("taylor_green_3d_bench", p, params, scheme, Domain((0.0,) * 3, (1.0,) * 3, (True,) * 3),
                 steps * dt * (1 - 1e-9))
    return pb, cfg, dt


def run_case(dim: int, n: int, frame: str, steps: int, devices: int = 1, precision: str = "float64",
             keep: bool = False, rounds: int = 1) -> dict:
    """One timed run (compile and stepping separate) of ``steps`` steps in one chunk (``keep``:
    the final conserved quantities under ``"q"``, for comparisons).

    ``rounds`` > 1 runs the compiled case again ``rounds - 1`` times: the best chunk time counts,
    and each repeat records the CPU seconds (user + system, ``os.times``) the process spent per
    step and the cores it kept busy (CPU time over wall time).  Both include the run's set-up
    (host neighbour build, Eulerian geometry, snapshot) but no compilation; CPU time per step is
    the contention-robust measure of the cost scaling on a shared machine."""
    from mlsph_jax.simulation import Simulation

    pb, cfg, dt = (_problem_2d if dim == 2 else _problem_3d)(n, frame, steps)
    sim = Simulation(pb, dt=dt, chunk=steps, max_steps=steps + 1, headroom=cfg["scheme"]["neighbor_headroom"],
                     devices=devices, precision=precision)
    t0 = time.perf_counter()
    res = sim.run(None, snapshots=1, progress=False, plots=False)
    total = time.perf_counter() - t0
    s = res.summary
    stepping = s["chunk_time_s"]  # the compiled chunks alone (no compilation, no set-up)
    repeats = []
    for _ in range(rounds - 1):
        w0, c0 = time.perf_counter(), os.times()
        s2 = sim.run(None, snapshots=1, progress=False, plots=False).summary
        w1, c1 = time.perf_counter(), os.times()
        cpu = c1.user + c1.system - c0.user - c0.system
        repeats.append({"stepping_s": s2["chunk_time_s"], "cpu_s_per_step": cpu / max(s2["n_steps"], 1),
                        "cores_busy": cpu / max(w1 - w0, 1e-12), "load": os.getloadavg()[0]})
        stepping = min(stepping, s2["chunk_time_s"])
    N = int(pb.particles.n)
    mem = s.get("chunk_memory_bytes") or {}
    return {"dim": dim, "n": n, "particles": N, "frame": frame, "devices": devices, "steps": s["n_steps"],
            "dt": dt, "compile_s": s["compile_time_s"], "stepping_s": stepping, "total_s": total,
            "seconds_per_step": stepping / max(s["n_steps"], 1),
            "particle_steps_per_s": N * s["n_steps"] / max(stepping, 1e-12),
            "memory_bytes_per_particle": (sum(mem.values()) / N) if mem else None,
            "status": s["status"], "precision": precision, "metrics": s["metrics"], "repeats": repeats,
            "cpu_s_per_step": min((r["cpu_s_per_step"] for r in repeats), default=None),
            **({"q": res.particles.q} if keep else {})}


def cost_exponent(rows: list[dict], key: str = "seconds_per_step") -> float | None:
    """Least-squares slope of log(``key``: wall or CPU seconds per step) against log N (None for
    fewer than 2 sizes or without the measure)."""
    import numpy as np

    if len(rows) < 2 or any(r.get(key) is None for r in rows):
        return None
    n = np.log([r["particles"] for r in rows])
    t = np.log([r[key] for r in rows])
    return float(np.polyfit(n, t, 1)[0])


def _line(r: dict) -> str:
    mem = r["memory_bytes_per_particle"]
    return (f"{r['dim']}D N={r['particles']:>8d} devices={r['devices']} {r['precision']} {r['frame']:>9s} "
            f"steps={r['steps']:>4d} "
            f"compile={r['compile_s']:6.2f} s  step={r['seconds_per_step'] * 1e3:9.2f} ms  "
            f"{r['particle_steps_per_s']:10.3e} particle-steps/s  "
            f"mem={'n/a' if mem is None else f'{mem:8.0f}'} B/particle"
            + ("" if r.get("cpu_s_per_step") is None else
               f"  cpu={r['cpu_s_per_step'] * 1e3:9.2f} ms/step "
               f"({max(x['cores_busy'] for x in r['repeats']):.2f} cores)"))


# --------------------------------------------------------------------------------------------
# devices: a subprocess with forced host devices
# --------------------------------------------------------------------------------------------

def device_runs(n: int, frame: str, steps: int, devices: int = 2) -> list[dict]:
    env = {**os.environ, "XLA_FLAGS": f"--xla_force_host_platform_device_count={devices}",
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, __file__, "--worker-devices", str(devices), "--worker-n", str(n), "--frame", frame,
           "--steps", str(steps)]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=3600)
    lines = [s for s in proc.stdout.splitlines() if s.startswith("RESULT")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"device worker failed (exit {proc.returncode}): {proc.stderr[-2000:]}")
    return json.loads(lines[-1][len("RESULT"):])


def worker_devices(devices: int, n: int, frame: str, steps: int) -> None:
    rows = [run_case(2, n, frame, steps, devices=d) for d in sorted({1, devices})]
    print("RESULT" + json.dumps(rows))


# --------------------------------------------------------------------------------------------
# JAX-SPH in its own virtual environment
# --------------------------------------------------------------------------------------------

def jaxsph_python(log) -> str | None:
    """Interpreter of the JAX-SPH environment (created and installed on first use), or None
    when the installation fails (``log`` receives the reason)."""
    py = VENV / "bin" / "python"
    try:
        if not py.exists():
            subprocess.run([sys.executable, "-m", "venv", str(VENV)], check=True, capture_output=True, text=True)
        ok = subprocess.run([str(py), "-c", "import jax_sph"], capture_output=True).returncode == 0
        if not ok:
            # jax-sph 0.1.0 declares Python <= 3.11 (i.e. <= 3.11.0): install it with
            # --ignore-requires-python but without dependencies, then its declared requirements
            # with pip's usual Python-version checks (else pip picks releases for newer Pythons)
            log("installing jax-sph into " + str(VENV) + " (pip, from the registry) ...")
            pip = [str(py), "-m", "pip", "install", "-q"]
            reqs = "import importlib.metadata as m; print('\\n'.join(m.requires('jax-sph') or []))"
            for cmd in ([*pip, "--ignore-requires-python", "--no-deps", "jax-sph"], None):
                if cmd is None:
                    req = subprocess.run([str(py), "-c", reqs], capture_output=True, text=True, check=True)
                    cmd = [*pip, *[r for r in req.stdout.splitlines() if r.strip()]]
                proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1800)
                if proc.returncode != 0:
                    err = "\n".join(s for s in proc.stderr.splitlines() if not s.startswith("WARNING"))
                    log("JAX-SPH skipped: pip install jax-sph failed: " + err.strip()[-1500:])
                    return None
        return str(py)
    except (OSError, subprocess.SubprocessError) as e:
        log(f"JAX-SPH skipped: could not create its environment: {e}")
        return None


def jaxsph_run(py: str, n: int, steps: int) -> dict:
    proc = subprocess.run([py, str(JAXSPH_DRIVER), "--n", str(n), "--steps", str(steps)], capture_output=True,
                          text=True, timeout=3600, env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"})
    lines = [s for s in proc.stdout.splitlines() if s.startswith("RESULT")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"JAX-SPH run failed (exit {proc.returncode}): {proc.stderr[-2000:]}")
    return json.loads(lines[-1][len("RESULT"):])


# --------------------------------------------------------------------------------------------

def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small sizes and few steps (a minute or two)")
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--sizes2d", type=int, nargs="*", default=None, help="n of the n x n runs")
    ap.add_argument("--sizes3d", type=int, nargs="*", default=None, help="n of the n^3 runs")
    ap.add_argument("--device-sizes", type=int, nargs="*", default=None, help="n of the 1-vs-2-device runs")
    ap.add_argument("--jaxsph-sizes", type=int, nargs="*", default=None, help="n of the JAX-SPH comparison")
    ap.add_argument("--precision-sizes", type=int, nargs="*", default=None,
                    help="n of the float64-vs-float32 runs (run.precision)")
    ap.add_argument("--frame", default="eulerian")
    ap.add_argument("--no-jaxsph", action="store_true")
    ap.add_argument("--jaxsph-rounds", type=int, default=3,
                    help="alternating rounds (JAX-SPH, ours) per size; the best round of each is compared")
    ap.add_argument("--rounds", type=int, default=1,
                    help="runs per size of the N sweep (repeats: best chunk time, CPU seconds per step)")
    ap.add_argument("--out", default=str(OUT / "bench_scale.json"))
    ap.add_argument("--worker-devices", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--worker-n", type=int, default=0, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    steps = a.steps or (10 if a.quick else 20)
    if a.worker_devices:
        worker_devices(a.worker_devices, a.worker_n, a.frame, steps)
        return 0
    sizes2d = a.sizes2d if a.sizes2d is not None else ([32, 64, 100] if a.quick else [32, 64, 100, 200, 316])
    sizes3d = a.sizes3d if a.sizes3d is not None else ([8, 12] if a.quick else [10, 16, 24])
    dev_sizes = a.device_sizes if a.device_sizes is not None else ([100] if a.quick else [100, 200])
    prec_sizes = a.precision_sizes if a.precision_sizes is not None else ([100] if a.quick else [100, 200])
    jx_sizes = a.jaxsph_sizes if a.jaxsph_sizes is not None else ([50] if a.quick else [50, 200])

    def log(msg):
        print(msg, flush=True)

    out = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "python": platform.python_version(),
                       "load_average_at_start": os.getloadavg()},
           "steps": steps, "frame": a.frame}
    rows2, rows3 = [], []
    for n in sizes2d:
        rows2.append(run_case(2, n, a.frame, steps, rounds=a.rounds))
        log(_line(rows2[-1]))
    for n in sizes3d:
        rows3.append(run_case(3, n, a.frame, steps, rounds=a.rounds))
        log(_line(rows3[-1]))
    out["sweep_2d"], out["sweep_3d"] = rows2, rows3
    out["cost_exponent_2d"], out["cost_exponent_3d"] = cost_exponent(rows2), cost_exponent(rows3)
    log(f"cost exponent (seconds per step ~ N^a): 2D a = {out['cost_exponent_2d']}, 3D a = {out['cost_exponent_3d']}")
    out["cpu_cost_exponent_2d"] = cost_exponent(rows2, "cpu_s_per_step")
    out["cpu_cost_exponent_3d"] = cost_exponent(rows3, "cpu_s_per_step")
    if a.rounds > 1:
        log(f"cost exponent (CPU seconds per step ~ N^a): 2D a = {out['cpu_cost_exponent_2d']}, "
            f"3D a = {out['cpu_cost_exponent_3d']}")

    out["precision"] = []
    for n in prec_sizes:
        import numpy as np

        r64, r32 = (run_case(2, n, a.frame, steps, precision=pr, keep=True) for pr in ("float64", "float32"))
        q64, q32 = np.asarray(r64.pop("q")), np.asarray(r32.pop("q"), np.float64)
        diff = float(np.abs(q64 - q32).max() / np.abs(q64).max())
        l2 = (r64["metrics"]["l2_velocity_error"], r32["metrics"]["l2_velocity_error"])
        speedup = r64["seconds_per_step"] / r32["seconds_per_step"]
        out["precision"].append({"n": n, "float64": r64, "float32": r32, "speedup_32_over_64": speedup,
                                 "max_rel_q_difference": diff, "l2_velocity_error": l2})
        log(_line(r64))
        log(_line(r32))
        log(f"N={n * n}: float32 / float64 speed-up {speedup:.2f}x; max |q32 - q64| / max |q64| = {diff:.2e}; "
            f"l2 velocity error {l2[0]:.6e} (float64) vs {l2[1]:.6e} (float32)")

    out["devices"] = []
    for n in dev_sizes:
        try:
            rows = device_runs(n, a.frame, steps)
        except RuntimeError as e:
            log(str(e))
            continue
        for r in rows:
            log(_line(r))
        speedup = rows[0]["seconds_per_step"] / rows[-1]["seconds_per_step"]
        out["devices"].append({"n": n, "runs": rows, "speedup_2_over_1": speedup})
        log(f"N={rows[0]['particles']}: 2 host devices / 1 device speed-up {speedup:.2f}x")

    out["jaxsph"] = []
    if not a.no_jaxsph:
        py = jaxsph_python(log)
        if py is not None:
            for n in jx_sizes:
                # alternate the two codes (JAX-SPH, ours, JAX-SPH, ours, ...) with the same step count and
                # keep each one's best round: load changes on a shared machine hit both alike
                jx_rounds, our_rounds = [], []
                try:
                    for _ in range(a.jaxsph_rounds):
                        jx_rounds.append(jaxsph_run(py, n, max(steps, 100)))
                        our_rounds.append(run_case(2, n, a.frame, max(steps, 100)))
                except RuntimeError as e:
                    log(f"JAX-SPH n={n} failed: {e}")
                    continue
                jx = max(jx_rounds, key=lambda r: r["particle_steps_per_s"])
                ours = max(our_rounds, key=lambda r: r["particle_steps_per_s"])
                ratio = ours["particle_steps_per_s"] / jx["particle_steps_per_s"]
                out["jaxsph"].append({"n": n, "jaxsph": jx, "mlsph_jax": ours, "ratio_ours_over_jaxsph": ratio,
                                      "rounds": a.jaxsph_rounds,
                                      "jaxsph_rounds": [r["particle_steps_per_s"] for r in jx_rounds],
                                      "mlsph_jax_rounds": [r["particle_steps_per_s"] for r in our_rounds],
                                      "load_average": os.getloadavg()})
                log(f"N={n * n}: JAX-SPH {jx['particle_steps_per_s']:.3e} particle-steps/s "
                    f"(compile {jx['compile_s']:.2f} s, dt {jx['dt']:.3g}); ours {ours['particle_steps_per_s']:.3e} "
                    f"(dt {ours['dt']:.3g}); ratio ours/JAX-SPH = {ratio:.2f} (best of {a.jaxsph_rounds} alternating "
                    f"rounds, load {os.getloadavg()[0]:.1f})")
    else:
        log("JAX-SPH skipped (--no-jaxsph)")
    out["load_average_at_end"] = os.getloadavg()
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=1) + "\n")
    log(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
