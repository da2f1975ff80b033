"""Sensitivities and calibration of whole simulations (``mlsph sensitivity`` / ``mlsph calibrate``).

Objectives (``--of``) are differentiable scalars of a run made by
:func:`mlsph_jax.differentiable.make_simulate`:

* ``<diagnostic>_final`` for every recorded diagnostic (``ke``, ``mass``, ``momentum_x``, ...
  and the case's own, see :func:`objective_names`);
* the case's differentiable metrics (``Problem.differentiable_metrics(particles, t, params)``)
  at the end of the run, e.g. ``ke_rel_error`` for Taylor-Green, ``cd`` / ``cl`` for the cylinder;
* time averages (:data:`TIME_AVERAGES`) of every diagnostic and every differentiable metric over
  a window [t_start, t_end] of the run (``window``, ``mlsph sensitivity --window T_START T_END``;
  default the whole run [0, t_end]): ``<name>_mean`` = (1 / (t_end - t_start)) * integral of the
  quantity over the window, and ``<name>_rms`` = the root mean square of its fluctuation about
  that mean, sqrt(mean((q - mean(q))^2)), e.g. ``cd_mean``, ``cl_mean``, ``cl_rms``, ``ke_mean``.
  They are accumulated inside the differentiated run at every step (the trapezoidal rule on the
  step grid, :func:`mlsph_jax.differentiable.window_weights`), not from the recorded series, so
  they do not depend on ``record_every``; the fluctuation is accumulated by a weighted Welford
  update (no cancellation between <q^2> and <q>^2).  The rms has no derivative where the
  fluctuation is zero (a steady or mirror-symmetric flow: the square root at 0): :func:`sensitivity`
  refuses such an objective (InputError) rather than return NaN.

:func:`sensitivity` returns d objective / d parameter for the requested parameters (dotted keys
of the parameter pytree, e.g. ``physics.mu``, ``eos.c0``, ``boundary.wall_velocity``) and, with
``check_fd``, central finite differences with the step used and the relative disagreement.
Both functions differentiate in forward or reverse mode (``mode``, :data:`MODES`): by default
forward mode for a single scalar parameter component, where it is the cheaper of the two and
stores nothing per step, and reverse mode (with the run's ``checkpoint`` strategy) otherwise.

:func:`calibrate` fits parameters to observed time series (a CSV with a ``t`` column and columns
named after diagnostics) with optax on relative coordinates theta = theta_0 (1 + s), so one
learning rate suits parameters of any magnitude.  Loss: the mean over columns of the mean squared
misfit at the observed times (the simulated series linearly interpolated), each column divided by
the mean square of its observations.

A problem whose initial particles depend on its parameters (the ``cylinder`` case: the
body-fitted layout follows ``geometry.body.*``, docs/architecture.md decision 65) carries
``particles_at(params) -> Particles``; every objective starts its run from
:func:`initial_particles`, so shape derivatives include the motion of the layout.

Every forward run is checked: the :class:`~mlsph_jax.differentiable.SimOutput` (with its status
word) is returned as auxiliary output of the differentiated function and checked on the host
(:func:`mlsph_jax.differentiable.check`), so a run that fails (NaN, inadmissible state, a step
above the CFL limit, neighbour overflow, ...) raises :class:`~mlsph_jax.errors.SimulationError`
naming step, time, particle and cause instead of returning NaN or a frozen state's numbers.  A
``n_steps`` above the CFL limit of the initial state is refused before running (InputError).
"""

from __future__ import annotations

import csv
import json
from collections.abc import Mapping, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .approximation import block_scan
from .differentiable import check, make_simulate, param_paths, with_param
from .errors import InputError
from .state import Params


def _simulate_for(problem, **kw):
    return make_simulate(problem, **kw)


def initial_particles(problem, params: Params):
    """The run's initial particles for ``params``: ``problem.particles_at(params)`` when the
    problem's layout depends on its parameters (a body-fitted layout), else ``problem.particles``."""
    return problem.particles if problem.particles_at is None else problem.particles_at(params)


#: The time averages over a window of the run that every diagnostic and differentiable metric
#: has as an objective (``<name>_<average>``; module docstring): the mean and the rms of the
#: fluctuation about it.
TIME_AVERAGES = ("mean", "rms")


def time_average(avg: Mapping, reduction: str) -> jax.Array:
    """The time average ``reduction`` (one of :data:`TIME_AVERAGES`) of a quantity from its
    accumulated ``{"mean": <q>, "variance": <(q - <q>)^2>}`` (``SimOutput.averages[name]``, a
    weighted Welford accumulation in the run): ``mean`` is <q>; ``rms`` is sqrt(variance), the
    rms of the fluctuation about the window's mean.  The square root is taken only where the
    variance is positive, so a vanishing fluctuation gives 0 with a zero (not NaN) derivative;
    :func:`sensitivity` refuses an rms objective whose value is 0, whose derivative is undefined."""
    if reduction not in TIME_AVERAGES:
        raise InputError(f"invalid time-average reduction {reduction!r}; allowed: {', '.join(TIME_AVERAGES)}")
    if reduction == "mean":
        return avg["mean"]
    v = avg["variance"]
    return jnp.where(v > 0, jnp.sqrt(jnp.where(v > 0, v, 1.0)), 0.0)


def _objectives(problem, simulate) -> dict[str, tuple[str, str, str]]:
    """The objectives of ``problem``: name -> (source, quantity, reduction), source ``"series"``
    (a recorded diagnostic) or ``"metric"`` (a differentiable metric), reduction ``"final"`` or
    one of :data:`TIME_AVERAGES`.  The only list of objective names."""
    series = list(jax.eval_shape(lambda p: simulate.diagnostics(p, 0.0, problem.params), problem.particles))
    out = {f"{k}_final": ("series", k, "final") for k in series}
    dm = getattr(problem, "differentiable_metrics", None)
    metrics = [] if dm is None else list(jax.eval_shape(lambda p: dm(p, 0.0, problem.params), problem.particles))
    out.update({m: ("metric", m, "final") for m in metrics})
    for src, names in (("series", series), ("metric", metrics)):
        out.update({f"{k}_{a}": (src, k, a) for k in names for a in TIME_AVERAGES})
    return out


def objective_names(problem, simulate) -> list[str]:
    """Objectives ``--of`` accepts for ``problem``."""
    return list(_objectives(problem, simulate))


def make_objective(problem, simulate, of: str, window=None):
    """``f(params) -> (scalar, SimOutput)`` for the objective named ``of``; ``window`` =
    (t_start, t_end) of a time average (default the whole run; refused for other objectives)."""
    objectives = _objectives(problem, simulate)
    if of not in objectives:
        raise InputError(f"invalid --of {of!r}; allowed: {', '.join(objectives)}")
    src, q, red = objectives[of]
    dm = getattr(problem, "differentiable_metrics", None)
    t_end = simulate.n_steps * simulate.dt
    if red == "final":
        if window is not None:
            raise InputError(f"invalid --window {tuple(window)!r} with --of {of!r}: a window applies to the time "
                             f"averages only; allowed: no window, or --of {q}_mean / {q}_rms "
                             f"({', '.join(TIME_AVERAGES)})")
        sim = simulate
    else:
        def average(p, t, params):   # only the quantity asked for is evaluated at every step
            return {q: (simulate.diagnostics if src == "series" else dm)(p, t, params)[q]}

        sim = make_simulate(problem, **simulate.options, average=average, window=window)

    def f(params):
        out = sim(params, initial_particles(problem, params))
        if red == "final":
            val = out.series[q][-1] if src == "series" else dm(out.particles, t_end, params)[q]
        else:
            val = time_average(out.averages[q], red)
        return val, out

    f.window = sim.window
    return f


#: How :func:`sensitivity` and :func:`calibrate` differentiate the run: ``reverse`` (``jax.grad``:
#: one forward run, then the step recomputations and transposes that ``checkpoint`` prescribes;
#: cost independent of the number of parameters), ``forward`` (``jax.jacfwd``: the run once with
#: one tangent per scalar parameter component carried along; no checkpoints, nothing stored per
#: step; cost grows with the components) or ``auto`` (forward up to :data:`FORWARD_MAX_COMPONENTS`
#: components, else reverse).  The only list of names.
MODES = ("auto", "reverse", "forward")

#: ``mode = "auto"`` differentiates in forward mode up to this many scalar parameter components
#: (the sizes of the ``wrt`` / ``fit`` parameters added up).  Measured on Taylor-Green
#: (docs/performance.md "Whole-run gradients measured again, and forward mode"): one tangent costs
#: 3.0-3.4x the forward run (10,000 particles) and 2.7-3.2x (2,500), reverse mode 3.6-4.9x with
#: ``checkpoint = "step"`` and 4.8x with the default ``"nested"``; a second tangent costs as much
#: as the first (5.6-7.3x for two), so forward mode pays for exactly one component.
FORWARD_MAX_COMPONENTS = 1


def check_mode(mode: str) -> None:
    """InputError naming ``mode`` (``--mode``), the value and :data:`MODES` unless it is one of them."""
    if mode not in MODES:
        raise InputError(f"invalid mode (--mode) {mode!r}; allowed: {', '.join(MODES)}")


def resolve_mode(mode: str, theta: Mapping) -> str:
    """``"forward"`` or ``"reverse"``: ``mode`` with ``"auto"`` resolved by the number of scalar
    components of the parameters ``theta`` (:data:`MODES`); an unknown mode is an InputError."""
    check_mode(mode)
    if mode != "auto":
        return mode
    n = sum(int(np.size(v)) for v in theta.values())
    return "forward" if n <= FORWARD_MAX_COMPONENTS else "reverse"


def value_and_grad(fun, mode: str, scan_blocks: bool = False):
    """``jax.value_and_grad(fun, has_aux=True)`` in ``mode`` (``"forward"`` or ``"reverse"``):
    ``fun(theta) -> (scalar, aux)``; returns ``((value, aux), grads)`` with ``grads`` shaped like
    ``theta``.  Forward mode is ``jax.jacfwd`` of the scalar: the primal run is not batched (the
    tangents are), so value and aux come from the one run that carries every tangent.
    ``scan_blocks``: forward mode's tangent through the blocked stencil passes' scanned-block
    derivative instead of their own loop JVP (for comparison only; same derivative, dearer)."""
    if mode == "reverse":
        return jax.value_and_grad(fun, has_aux=True)
    if mode != "forward":
        raise InputError(f"invalid mode (--mode) {mode!r}; allowed: forward, reverse")

    def with_value(theta):
        val, aux = fun(theta)
        return val, (val, aux)

    def vg(theta):
        # traced with the blocked stencil passes' own loop JVP (approximation.block_scan off): the
        # scanned-block derivative exists for the transpose (decision 76); a tangent needs no
        # transpose, and without the stacking copies it costs 14 % less at 10,000 particles, with
        # the same derivative to the last bit (docs/performance.md "Whole-run gradients measured
        # again, and forward mode")
        with block_scan(scan_blocks):
            grads, (val, aux) = jax.jacfwd(with_value, has_aux=True)(theta)
        return (val, aux), grads

    return vg


#: Parameters a run depends on only when its scheme has the term that reads them (the scheme's
#: switch): without it the derivative is exactly zero, and a finite-difference check agrees.
_SWITCHED = {"physics.mu": ("viscous", "the scheme has no viscous stress (physics.mu = 0, e.g. case.inviscid = true)",
                            "a run with physics.mu > 0"),
             "physics.kappa": ("heat_conduction", "the scheme has no heat conduction (physics.kappa = 0)",
                               "a run with physics.kappa > 0 (or a case's Prandtl number)")}


def _check_wrt(problem, wrt: Sequence[str]):
    allowed = param_paths(problem.params)
    for k in wrt:
        if k not in allowed:
            raise InputError(f"invalid --wrt {k!r}; allowed: {', '.join(allowed)}")
        if k in _SWITCHED and not getattr(problem.scheme, _SWITCHED[k][0]):
            others = [a for a in allowed if a not in _SWITCHED or getattr(problem.scheme, _SWITCHED[a][0])]
            raise InputError(f"invalid --wrt {k!r}: {_SWITCHED[k][1]}, so the run does not depend on it (its "
                             f"derivative needs {_SWITCHED[k][2]}); allowed here: {', '.join(others)}")


def sensitivity(problem, wrt: Sequence[str], of: str, check_fd: bool = False, fd_rel: float = 1e-5,
                window=None, mode: str = "auto", **simulate_kw) -> dict:
    """Gradient of objective ``of`` with respect to each parameter in ``wrt`` (module doc);
    ``window`` = (t_start, t_end) of a time-averaged objective (default the whole run);
    ``mode``: one of :data:`MODES` (the result's ``mode`` says which one ran)."""
    _check_wrt(problem, wrt)
    theta = {k: jnp.asarray(problem.params[k], jnp.float64) for k in wrt}
    mode = resolve_mode(mode, theta)
    simulate = _simulate_for(problem, **simulate_kw)
    f = make_objective(problem, simulate, of, window=window)

    def g(th):
        p = problem.params
        for k, v in th.items():
            p = with_param(p, k, v)
        return f(p)

    (value, out), grads = jax.jit(value_and_grad(g, mode))(theta)
    check(out, simulate, problem.params)
    _check_gradient(of, float(value), grads, f.window)
    result = {"objective": of, "value": float(value), "n_steps": simulate.n_steps, "dt": simulate.dt,
              "mode": mode, "gradients": {}}
    if f.window is not None:
        result["window"] = list(f.window)
    g_jit = jax.jit(g) if check_fd else None

    def fj(th):   # a finite-difference run, checked like the others
        val, o = g_jit(th)
        p = problem.params
        for k, v in th.items():
            p = with_param(p, k, v)
        check(o, simulate, p)
        return val

    for k in wrt:
        gk = np.asarray(grads[k])
        entry = {"value": np.asarray(theta[k]).tolist(), "gradient": gk.tolist()}
        if check_fd:
            base = np.asarray(theta[k], float)
            flat = base.reshape(-1)
            fd, steps = np.zeros_like(flat), np.zeros_like(flat)
            for i in range(flat.size):
                h = fd_rel * (abs(flat[i]) if flat[i] != 0 else 1.0)
                up, dn = flat.copy(), flat.copy()
                up[i] += h
                dn[i] -= h
                f_up = float(fj({**theta, k: jnp.asarray(up.reshape(base.shape))}))
                f_dn = float(fj({**theta, k: jnp.asarray(dn.reshape(base.shape))}))
                fd[i], steps[i] = (f_up - f_dn) / (2 * h), h
            fd, steps = fd.reshape(base.shape), steps.reshape(base.shape)
            rel = np.abs(gk - fd) / np.maximum(np.maximum(np.abs(gk), np.abs(fd)), 1e-300)
            entry.update(fd=fd.tolist(), fd_step=steps.tolist(), rel_disagreement=rel.tolist())
            fd10 = None
            if fd_verdict(gk, fd)["verdict"] != "agree":   # a second step tells a step problem from a derivative one
                fd10 = np.zeros_like(flat)
                for i in range(flat.size):
                    h = 10 * steps.reshape(-1)[i]
                    up, dn = flat.copy(), flat.copy()
                    up[i] += h
                    dn[i] -= h
                    fd10[i] = (float(fj({**theta, k: jnp.asarray(up.reshape(base.shape))}))
                               - float(fj({**theta, k: jnp.asarray(dn.reshape(base.shape))}))) / (2 * h)
                fd10 = fd10.reshape(base.shape)
                entry["fd_10_step"] = fd10.tolist()
            entry.update(fd_verdict(gk, fd, fd10, mood=problem.scheme.limiter == "mood"))
        result["gradients"][k] = entry
    return result


def _check_gradient(of: str, value: float, grads: Mapping, window) -> None:
    """Refuse (InputError) an objective whose derivative is undefined or not finite instead of
    reporting NaN: an rms of a fluctuation that is exactly 0 over the window (the square root at
    0), or any non-finite gradient."""
    over = "" if window is None else f" over the window [{window[0]:.6g}, {window[1]:.6g}]"
    if of.endswith("_rms") and value == 0.0:
        raise InputError(f"invalid --of {of!r}: {of} is 0{over} (the quantity does not fluctuate): its gradient is "
                         "undefined (the square root at 0); allowed: a quantity that fluctuates over the window, "
                         f"or --of {of[:-4]}_mean")
    bad = [k for k, g in grads.items() if not np.all(np.isfinite(np.asarray(g)))]
    if bad:
        raise InputError(f"invalid --of {of!r}: its value is {value:.6g}{over} but its gradient with respect to "
                         f"{', '.join(bad)} is not finite (the objective is not differentiable there); allowed: "
                         "another objective or window")


#: Largest relative AD/FD difference called agreement (central differences at the default
#: relative step 1e-5 are accurate to ~1e-9 relative for a smooth objective).
AGREE_TOL = 1e-4


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    """max |a - b| relative to the largest entry of either (per parameter, so that a component
    that is zero in both is not a 100 % disagreement of round-off)."""
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(a))), float(np.max(np.abs(b))), 1e-300))


def fd_verdict(gradient, fd, fd_10_step=None, *, mood: bool = False) -> dict:
    """``{"verdict": "agree"|"disagree", "rel_difference": max relative difference, "hint": ...}``
    of an AD gradient against central finite differences ``fd`` (and, when they disagree, the
    differences ``fd_10_step`` at a ten times larger step).

    Hints: FD that change with the step point at the FD side (the step crosses a switch: MOOD
    demotions, a kink such as the |u.n| of a wave speed, a max/min; or is too large / too small
    for round-off); FD that are stable across steps while AD differs point at the derivative of a
    non-smooth operation (AD differentiates the branch taken: MOOD's demotion set, |u.n| at 0)."""
    g, f = np.asarray(gradient, float), np.asarray(fd, float)
    rel = _rel(g, f)
    if rel <= AGREE_TOL:
        return {"verdict": "agree", "rel_difference": rel, "hint": ""}
    hints = []
    if fd_10_step is not None:
        f10 = np.asarray(fd_10_step, float)
        step_rel = _rel(f10, f)
        if step_rel > AGREE_TOL:
            hints.append(f"the finite differences change by {step_rel:.1e} (relative) when the step grows 10x: the "
                         "objective is not smooth at the step's scale (a kink such as |u.n| in a wave speed, a "
                         "max/min, MOOD switching) or the step is badly sized; try another --fd-rel (1e-4, 1e-6)")
        else:
            hints.append(f"the finite differences are stable across steps ({step_rel:.1e}), so the AD derivative "
                         "is that of the branch taken at a non-smooth operation (|u.n| at 0, a max/min, a limiter)")
    if mood:
        hints.append("MOOD is on: a perturbed run may demote other particles (a discrete switch AD does not see); "
                     "compare with scheme.limiter = \"none\" at first order")
    return {"verdict": "disagree", "rel_difference": rel, "hint": "; ".join(hints)}


def read_target(path: str | Path) -> dict[str, np.ndarray]:
    """Observed time series: a CSV with a header row, a ``t`` column and diagnostic columns."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"invalid --target {str(path)!r}: the file does not exist")
    with path.open() as fh:
        rows = list(csv.reader(fh))
    if len(rows) < 2 or "t" not in rows[0]:
        raise InputError(f"invalid --target {str(path)!r}: needs a header with a 't' column and at least one row")
    head = [h.strip() for h in rows[0]]
    try:
        data = np.asarray([[float(v) for v in r] for r in rows[1:] if r], float)
    except ValueError as e:
        raise InputError(f"invalid --target {str(path)!r}: non-numeric value ({e})") from None
    return {h: data[:, i] for i, h in enumerate(head)}


OPTIMIZERS = ("lbfgs", "adam")


def calibrate(problem, fit: Sequence[str], target: Mapping[str, np.ndarray], steps: int = 50, lr: float | None = None,
              progress: bool = True, callback=None, optimizer: str = "lbfgs", tol: float | None = None,
              mode: str = "auto", **simulate_kw) -> dict:
    """Fit ``fit`` parameters to ``target`` series with optax (module docstring).

    ``target`` columns other than ``t`` that the run does not record (e.g. the ``ke_exact`` of
    a ``timeseries.csv`` written by ``mlsph run``) are ignored and listed in the result's
    ``ignored_columns``; at least one must be recorded.  ``tol``: stop once the loss is at or
    below it (``stopped`` = ``"tol"``); the fit also stops when the loss changed by less than
    :data:`PLATEAU_RTOL` (relative) in each of the last two iterations (``"plateau"``), else after
    ``steps`` iterations (``"steps"``).

    ``optimizer``: ``lbfgs`` (default; optax L-BFGS with a zoom line search, which for these
    smooth few-parameter fits converges in a handful of iterations; a given ``lr`` replaces the
    line search by that fixed step scale) or ``adam`` (learning rate ``lr``, default 0.05, with
    cosine decay to zero over ``steps``, so that it settles instead of oscillating).

    ``mode``: how the loss is differentiated, one of :data:`MODES` (the result's ``mode``).
    """
    import optax

    if optimizer not in OPTIMIZERS:
        raise InputError(f"invalid optimizer={optimizer!r}; allowed: {', '.join(OPTIMIZERS)}")
    if lr is not None and not (np.isfinite(lr) and lr > 0):
        raise InputError(f"invalid lr={lr!r}; allowed: a finite float > 0 (or None for the default)")
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
        raise InputError(f"invalid steps={steps!r}; allowed: an integer >= 0")
    if tol is not None and not (np.isfinite(tol) and tol > 0):
        raise InputError(f"invalid tol={tol!r}; allowed: a finite float > 0 (or None: run all steps)")
    _check_wrt(problem, fit)
    mode = resolve_mode(mode, {k: problem.params[k] for k in fit})
    simulate = _simulate_for(problem, **simulate_kw)
    shape = jax.eval_shape(simulate, problem.params, problem.particles)
    cols = [c for c in target if c != "t" and c in shape.series]
    ignored = [c for c in target if c != "t" and c not in shape.series]
    if not cols:
        raise InputError(f"invalid target columns {ignored}: none is recorded by the run; allowed: t and at least "
                         f"one of {', '.join(shape.series)}")
    t_obs = jnp.asarray(target["t"])
    obs = {c: jnp.asarray(target[c]) for c in cols}
    scale = {c: jnp.maximum(jnp.mean(obs[c] ** 2), 1e-300) for c in cols}
    theta0 = {k: jnp.asarray(problem.params[k], jnp.float64) for k in fit}

    def loss(s):
        prm = _params_at(problem.params, fit, theta0, s)
        out = simulate(prm, initial_particles(problem, prm))
        terms = [jnp.mean((jnp.interp(t_obs, out.times, out.series[c]) - obs[c]) ** 2) / scale[c] for c in cols]
        return sum(terms) / len(terms), out

    loss_vg = value_and_grad(loss, mode)
    vg = jax.jit(loss_vg)

    def trial_loss(z):
        """The line search's trial runs: a failed run is an infinite loss (the step shrinks)
        rather than the loss of its frozen last good state; accepted points are re-run by
        ``vg`` and checked on the host."""
        val, out = loss(z)
        return jnp.where(out.status == 0, val, jnp.inf)

    if mode == "forward":
        # optax's zoom line search differentiates value_fn with jax.value_and_grad (reverse mode):
        # a custom VJP whose forward pass is the forward-mode derivative keeps its trial runs in
        # forward mode too (one tangent, nothing stored per step); the pullback only scales it
        trial_loss = jax.custom_vjp(trial_loss)

        def trial_fwd(z):
            (val, out), g = loss_vg(z)
            ok = out.status == 0
            return jnp.where(ok, val, jnp.inf), jax.tree_util.tree_map(lambda gi: jnp.where(ok, gi, 0.0), g)

        trial_loss.defvjp(trial_fwd, lambda g, ct: (jax.tree_util.tree_map(lambda gi: ct * gi, g),))

    s = {k: jnp.zeros_like(v) for k, v in theta0.items()}
    if optimizer == "adam":
        opt = optax.adam(optax.cosine_decay_schedule(0.05 if lr is None else lr, max(steps, 1)))

        @jax.jit
        def advance(s, state, val, g):
            upd, state = opt.update(g, state, s)
            return optax.apply_updates(s, upd), state
    else:
        opt = optax.lbfgs() if lr is None else optax.lbfgs(learning_rate=lr, linesearch=None)

        @jax.jit
        def advance(s, state, val, g):
            upd, state = opt.update(g, state, s, value=val, grad=g, value_fn=trial_loss)
            return optax.apply_updates(s, upd), state
    state = opt.init(s)
    history = []
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=steps, unit="it")
    out = None
    stopped = "steps"
    for it in range(steps + 1):
        (val, out), g = vg(s)
        check(out, simulate, _params_at(problem.params, fit, theta0, s))
        current = {k: (theta0[k] * (1.0 + s[k])).tolist() for k in fit}
        history.append({"iteration": it, "loss": float(val), "params": current})
        if callback is not None:
            callback(history[-1])
        if bar is not None:
            bar.set_postfix(loss=f"{float(val):.3e}", **{k: f"{np.ravel(v)[0]:.6g}" for k, v in current.items()})
            if it:
                bar.update(1)
        if tol is not None and float(val) <= tol:
            stopped = "tol"
            break
        if it >= 2 and abs(history[-2]["loss"] - float(val)) <= PLATEAU_RTOL * abs(history[-2]["loss"]) \
                and abs(history[-3]["loss"] - history[-2]["loss"]) <= PLATEAU_RTOL * abs(history[-3]["loss"]):
            stopped = "plateau"   # two iterations without a relative decrease of PLATEAU_RTOL
            break
        if it == steps:
            break
        s, state = advance(s, state, val, g)
    if bar is not None:
        bar.close()
    return {"fit": list(fit), "history": history, "final": history[-1]["params"], "loss": history[-1]["loss"],
            "stopped": stopped, "tol": tol, "mode": mode, "columns": cols, "ignored_columns": ignored,
            "series": {c: np.asarray(out.series[c]).tolist() for c in cols}, "times": np.asarray(out.times).tolist(),
            "target": {k: np.asarray(target[k]).tolist() for k in ["t", *cols]}}


#: Relative loss change below which two consecutive iterations count as a plateau (the fit stops).
PLATEAU_RTOL = 1e-9


def _params_at(params: Params, fit: Sequence[str], theta0, s) -> Params:
    """The parameters at relative coordinates ``s`` (theta = theta_0 (1 + s))."""
    for k in fit:
        params = with_param(params, k, theta0[k] * (1.0 + s[k]))
    return params


def write_calibration(out_dir: str | Path, result: Mapping) -> None:
    """history.json and calibration.png (loss per iteration, fitted vs observed series)."""
    from .plotting import subplots

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "history.json").write_text(json.dumps(result, indent=2))
    cols = list(result["series"])
    fig, axes = subplots(1, 1 + len(cols), figsize=(4.5 * (1 + len(cols)), 3.4))
    axes = np.atleast_1d(axes)
    axes[0].semilogy([h["loss"] for h in result["history"]], "k.-")
    axes[0].set_xlabel("iteration")
    axes[0].set_title("loss")
    for ax, c in zip(axes[1:], cols, strict=True):
        ax.plot(result["target"]["t"], result["target"][c], "o", mfc="none", label="target")
        ax.plot(result["times"], result["series"][c], "-", label="fitted run")
        ax.set_xlabel("t")
        ax.set_title(c)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "calibration.png", dpi=110)
