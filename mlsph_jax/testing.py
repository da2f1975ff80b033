"""Shared fixtures for the test suite and the experiments: particle layouts, small problems and
the run fingerprints that hold refactors to the numbers.

Nothing here is numerics: these are the inputs and the bookkeeping that ``tests/`` and
``experiments/`` would otherwise each write again (tests never import each other or the
experiments; experiments never import private functions).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

#: Folder of the built-in configs (the repository's ``configs/``).
CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"

#: Per built-in config, the ``--set`` overrides of its reduced regression run: the same scheme
#: and case on fewer particles and a shorter time, a few seconds each (``tests/test_config_regression.py``).
REDUCED_OVERRIDES: dict[str, tuple[str, ...]] = {
    "blast_2d": ("case.dx=8e-3", "time.t_end=5e-6"),
    "couette": ("case.ny=10", "case.nx=8", "time.t_end=0.2", "output.snapshots=2"),
    "lid_driven_cavity": ("case.n=12", "time.t_end=0.3", "output.snapshots=3"),
    "poiseuille": ("case.ny=10", "case.nx=8", "time.t_end=0.2", "output.snapshots=2"),
    "riemann_r1_tait": ("case.n=50", "time.t_end=5e-6"),
    "riemann_r2_tammann": ("case.n=60", "time.t_end=2e-5"),
    "sod_ideal_gas": ("case.n=60", "time.t_end=0.05"),
    "taylor_green_2d": ("case.n=12", "time.t_end=0.05", "output.snapshots=2"),
    "taylor_green_2d_mlsph": ("case.n=12", "time.t_end=0.1", "output.snapshots=2"),
}


def builtin_configs() -> list[str]:
    """Stems of the built-in configs (``configs/*.toml``)."""
    return sorted(p.stem for p in CONFIG_DIR.glob("*.toml"))


def _floats(d: Mapping) -> dict[str, float]:
    out = {}
    for k, v in d.items():
        if isinstance(v, bool):
            out[k] = float(v)
        elif isinstance(v, int | float):
            out[k] = float(v)
    return out


def run_fingerprint(config: str | Path, overrides: Sequence[str] = ()) -> dict:
    """Run a config in process (no outputs) and return the numbers a refactor must keep:
    step count, final time, case metrics, conservation drifts and MOOD statistics."""
    from . import config as config_mod
    from .cases import build_problem
    from .simulation import run_problem

    path = Path(config)
    if not path.suffix:
        path = CONFIG_DIR / f"{config}.toml"
    cfg = config_mod.load(path, [*overrides, "output.plots=false", "output.progress=false"])
    result = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True)
    s = result.summary
    return {"n_steps": int(s["n_steps"]), "t_final": float(s["t_final"]), "n_particles": int(s["n_particles"]),
            "metrics": _floats(s.get("metrics", {})), "conservation": _floats(s.get("conservation", {})),
            "mood": _floats(s.get("mood", {}))}


def fingerprint_differences(new: Mapping, ref: Mapping, rtol: float = 1e-12, atol: float = 1e-13) -> list[str]:
    """Entries of two fingerprints that differ by more than ``atol + rtol |ref|`` (empty: equal).

    Conservation drifts are round-off-sized differences of totals; they are compared with the
    absolute tolerance ``atol`` in units of the drift (itself relative to the total)."""
    problems = []
    for k in ("n_steps", "n_particles"):
        if new.get(k) != ref.get(k):
            problems.append(f"{k}: {new.get(k)} != {ref.get(k)}")
    for group in ("metrics", "conservation", "mood"):
        a, b = new.get(group, {}), ref.get(group, {})
        if set(a) != set(b):
            problems.append(f"{group} keys differ: {sorted(set(a) ^ set(b))}")
        for k in sorted(set(a) & set(b)):
            x, y = a[k], b[k]
            if math.isnan(x) and math.isnan(y):
                continue
            if not abs(x - y) <= atol + rtol * abs(y):
                problems.append(f"{group}.{k}: {x!r} != {y!r} (relative {abs(x - y) / max(abs(y), 1e-300):.2e})")
    t, tr = new.get("t_final"), ref.get("t_final")
    if t is None or tr is None or abs(t - tr) > rtol * abs(tr):
        problems.append(f"t_final: {t} != {tr}")
    return problems


# --------------------------------------------------------------------------------------------
# particle layouts
# --------------------------------------------------------------------------------------------

def lattice(n: int | Sequence[int], lower=0.0, upper=1.0, dim: int | None = None) -> np.ndarray:
    """Cell-centred Cartesian lattice in the box [lower, upper]^d: ``n`` per axis (an int, or one
    per axis), shape ``[prod(n), d]``."""
    if isinstance(n, int):
        n = (n,) * (dim or 1)
    d = len(n)
    lo = np.broadcast_to(np.asarray(lower, float), (d,))
    hi = np.broadcast_to(np.asarray(upper, float), (d,))
    axes = [lo[a] + (np.arange(n[a]) + 0.5) * (hi[a] - lo[a]) / n[a] for a in range(d)]
    grids = np.meshgrid(*axes, indexing="ij")
    return np.stack([g.ravel() for g in grids], axis=1)


def jittered_lattice(n: int | Sequence[int], amplitude: float = 0.2, seed: int = 0, lower=0.0, upper=1.0,
                     dim: int | None = None) -> np.ndarray:
    """:func:`lattice` with every point moved uniformly by up to ``amplitude`` times the spacing
    per axis (reproducible with ``seed``)."""
    x = lattice(n, lower, upper, dim)
    nn = np.asarray(n if not isinstance(n, int) else (n,) * x.shape[1], float)
    spacing = (np.broadcast_to(np.asarray(upper, float), (x.shape[1],))
               - np.broadcast_to(np.asarray(lower, float), (x.shape[1],))) / nn
    rng = np.random.default_rng(seed)
    return x + amplitude * spacing * rng.uniform(-1.0, 1.0, size=x.shape)


def random_cloud(n: int, dim: int, seed: int = 0) -> np.ndarray:
    """``n`` uniform random points in the unit box of dimension ``dim``."""
    return np.random.default_rng(seed).uniform(size=(n, dim))
