"""The ``mlsph`` command line (a stable contract; documented in README and docs/config.md).

    mlsph run [CONFIG] [--out DIR | --restart DIR] [--overwrite] [--set KEY=VALUE ...] [--quiet]
    mlsph validate CONFIG [--set KEY=VALUE ...]
    mlsph cases
    mlsph init CASE [--out FILE.toml]
    mlsph sensitivity CONFIG --wrt KEY [KEY ...] --of METRIC [--window T0 T1] [--check-fd] [--out DIR] [--set ...]
    mlsph calibrate CONFIG --fit KEY [KEY ...] --target FILE.csv [--steps N] [--lr X] [--out DIR] [--set ...]
    mlsph --version

CONFIG is a TOML file or the name of a built-in config (``mlsph run couette``, from any folder;
``mlsph cases`` lists them).  ``run`` without CONFIG runs the default case (Sod's shock tube, 200
particles, under a minute on 2 cores).  Exit codes: 0 success, 1 the simulation failed (NaN,
negative density, ...; the last good snapshot is on disk), 2 bad configuration or arguments
(also: an output folder that already holds a run, without --overwrite or --restart), 130
interrupted by Ctrl-C or SIGTERM (the last good state, summary.json with status "interrupted",
timeseries.csv and the plots are written; continue with --restart DIR).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

from . import __version__, compilation_cache
from .errors import ConfigError, DegreeFallbackWarning, InputError, MLSPHError, RunInterrupted, SimulationError

DEFAULT_CONFIG = """\
# Default case of `mlsph run`: Sod's shock tube (ideal gas), first-order MLSPH-ALE.
[case]
name = "riemann_1d"
left = { rho = 1.0, u = 0.0, p = 1.0 }
right = { rho = 0.125, u = 0.0, p = 0.1 }
x_interface = 0.5
domain = [0.0, 1.0]
n = 200

[eos]
kind = "ideal_gas"
gamma = 1.4

[scheme]
method = "mlsph_ale"
frame = "lagrangian"
reconstruction_degree = 0

[time]
t_end = 0.2

[output]
snapshots = 4
"""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mlsph", description="Meshless finite-volume particle simulations (MLSPH-ALE).")
    p.add_argument("--version", action="version", version=f"mlsph-jax {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    plug = argparse.ArgumentParser(add_help=False)
    plug.add_argument("--plugin", action="append", default=[], metavar="FILE.py|MODULE",
                      help="import a Python file or module first, e.g. one that registers your own flux, EOS or "
                           "case (docs/extending.md); repeatable")
    cache = argparse.ArgumentParser(add_help=False)
    cache.add_argument("--compilation-cache", metavar="DIR|off", default=None,
                       help="folder of JAX's persistent compilation cache: the next run of the same shapes and "
                            f"scheme loads its compiled programs instead of compiling them (default: "
                            f"${compilation_cache.ENV}, else a folder JAX already has ($JAX_COMPILATION_CACHE_DIR), "
                            "else $XDG_CACHE_HOME/mlsph_jax/xla or ~/.cache/mlsph_jax/xla); 'off' compiles "
                            "everything anew (mlsph_jax.compilation_cache)")
    r = sub.add_parser("run", parents=[plug, cache], help="run a case from a TOML config (default: Sod's shock tube)")
    r.add_argument("config", nargs="?", help="TOML config file or built-in config name, e.g. couette (omit for "
                                             "the default case; mlsph cases lists the names)")
    r.add_argument("--out", help="output folder (default: out/<config name>)")
    r.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE", action="extend",
                   help="override config keys, e.g. --set case.n=400 scheme.reconstruction_degree=1")
    r.add_argument("--quiet", action="store_true", help="no progress bar and no result paragraph")
    r.add_argument("--overwrite", action="store_true",
                   help="replace the run already in the output folder (its old files and plots are removed)")
    r.add_argument("--restart", metavar="DIR",
                   help="continue the interrupted or failed run in DIR from its last checkpoint (bit for bit as if "
                        "it had not stopped), or a run its steady-state test stopped, with --set case.steady_tol= a "
                        "smaller value; CONFIG is optional (default DIR/config.toml) and must match the run")
    r.add_argument("--distributed", action="store_true",
                   help="join a multi-process run (jax.distributed.initialize) before anything else: the cluster "
                        "from the environment (SLURM, Open MPI), or from --coordinator, --num-processes and "
                        "--process-id; every process runs the same command, with run.devices=0 for every device "
                        "of every process; process 0 writes the outputs (docs/performance.md, Launch)")
    r.add_argument("--coordinator", metavar="HOST:PORT", help="address of process 0 (implies --distributed)")
    r.add_argument("--num-processes", type=int, metavar="N", help="number of processes (implies --distributed)")
    r.add_argument("--process-id", type=int, metavar="K", help="this process, 0..N-1 (implies --distributed)")
    v = sub.add_parser("validate", parents=[plug], help="check a config without running it")
    v.add_argument("config", nargs="?", help="TOML config file or built-in config name")
    v.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE", action="extend")
    sub.add_parser("cases", parents=[plug], help="list the built-in cases and configs")
    i = sub.add_parser("init", parents=[plug], help="write a built-in config (or a case's defaults) to a file to edit")
    i.add_argument("name", metavar="CASE", help="built-in config name (e.g. couette) or case name (mlsph cases)")
    i.add_argument("--out", help="file to write (default: ./CASE.toml; an existing file is not overwritten)")
    diff_opts = argparse.ArgumentParser(add_help=False, parents=[plug, cache])
    diff_opts.add_argument("config", nargs="?", help="TOML config file or built-in config name")
    diff_opts.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE", action="extend")
    diff_opts.add_argument("--out", help="output folder (default: out/<config name>_<command>)")
    diff_opts.add_argument("--n-steps", type=int, default=None,
                           help="fixed number of SSP-RK3 steps (default: from the initial CFL step)")
    diff_opts.add_argument("--record-every", type=int, default=1, help="steps between recorded diagnostics")
    diff_opts.add_argument("--checkpoint", default="nested", choices=("none", "step", "nested"),
                           help="reverse-mode memory strategy (mlsph_jax.differentiable)")
    diff_opts.add_argument("--mode", default="auto",
                           help="automatic differentiation: reverse (cost independent of the number of "
                                "parameters), forward (one tangent per parameter component, nothing stored "
                                "per step) or auto (forward for a single scalar, else reverse; "
                                "mlsph_jax.sensitivity.MODES)")
    s_ = sub.add_parser("sensitivity", parents=[diff_opts],
                        help="d METRIC / d parameter of a whole run (automatic differentiation)")
    s_.add_argument("--wrt", nargs="+", required=True, metavar="KEY", help="parameters, e.g. physics.mu eos.c0")
    s_.add_argument("--of", required=True, metavar="METRIC",
                    help="objective, e.g. ke_final, cd (a differentiable metric at t_end), cd_mean / cl_rms (time "
                         "averages over --window); an unknown name lists them")
    s_.add_argument("--window", nargs=2, type=float, default=None, metavar=("T_START", "T_END"),
                    help="time window of a time-averaged objective (<name>_mean, <name>_rms): the trapezoidal "
                         "average over the run's steps in [T_START, T_END], 0 <= T_START < T_END <= t_end "
                         "(default: the whole run, 0 to t_end, start-up included, unlike the cylinder's "
                         "summary.json statistics that start after case.transient; a line says so)")
    s_.add_argument("--check-fd", action="store_true", help="compare with central finite differences")
    s_.add_argument("--fd-rel", type=float, default=1e-5, help="relative finite-difference step")
    c_ = sub.add_parser("calibrate", parents=[diff_opts], help="fit parameters to observed time series (optax)")
    c_.add_argument("--fit", nargs="+", required=True, metavar="KEY", help="parameters to fit, e.g. physics.mu")
    c_.add_argument("--target", required=True, help="CSV with a t column and diagnostic columns (e.g. ke)")
    c_.add_argument("--steps", type=int, default=50, help="optimiser iterations (at most)")
    c_.add_argument("--tol", type=float, default=None,
                    help="stop once the loss (mean squared misfit relative to the target's mean square) is <= TOL")
    c_.add_argument("--lr", type=float, default=None,
                    help="learning rate on relative parameter changes: Adam's initial rate (default 0.05, cosine "
                         "decay); with L-BFGS a fixed step scale replacing the zoom line search (default: line search)")
    c_.add_argument("--optimizer", default="lbfgs", choices=("lbfgs", "adam"), help="optax optimiser")
    c_.add_argument("--quiet", action="store_true", help="no progress bar (the per-iteration lines stay)")
    return p


def _load(path: str | None, overrides):
    from . import config

    if path is None:
        return config.loads(DEFAULT_CONFIG, overrides), "default"
    from .config.builtin import config_path

    file = config_path(path)
    return config.load(file, overrides), file.stem


def _fix_set(args) -> None:
    """``--set`` takes one or more values, so argparse hands it a config path that follows it
    (``mlsph validate --set case.n=50 configs/sod.toml``): a value without ``=`` is the CONFIG
    positional when that is empty; any other is an error naming it."""
    sets = getattr(args, "set", None)
    if not sets:
        return
    loose = [v for v in sets if "=" not in v]
    if len(loose) == 1 and getattr(args, "config", None) is None and hasattr(args, "config"):
        args.config = loose[0]
        args.set = [v for v in sets if v != loose[0]]
    elif loose:
        raise ConfigError(f"invalid --set value {loose[0]!r}; allowed: KEY=VALUE, e.g. case.n=400 (and at most one "
                          "CONFIG)")


def init_distributed(args) -> None:
    """``mlsph run --distributed`` (or any of ``--coordinator``, ``--num-processes``,
    ``--process-id``, which must then come together): ``jax.distributed.initialize`` before a
    plugin, a config or a computation touches JAX's backends.  Without the three options JAX reads
    the cluster from the environment (SLURM, Open MPI)."""
    opts = {"--coordinator": args.coordinator, "--num-processes": args.num_processes,
            "--process-id": args.process_id}
    given = [k for k, v in opts.items() if v is not None]
    if not (args.distributed or given):
        return
    if args.restart is not None:
        raise InputError(f"invalid --restart {args.restart} with {' '.join(given) or '--distributed'}: the checkpoint "
                         "is written and read by process 0 only; allowed: a restart in one process")
    if given and len(given) < 3:
        missing = [k for k in opts if k not in given]
        raise InputError(f"invalid {' '.join(f'{k} {opts[k]}' for k in given)} without {', '.join(missing)}; "
                         "allowed: all three of --coordinator HOST:PORT --num-processes N --process-id K, or none "
                         "(--distributed alone: the cluster from the environment)")
    kwargs = {}
    if given:
        coord, n, k = args.coordinator, args.num_processes, args.process_id
        host, sep, port = coord.rpartition(":")
        if not (sep and host and port.isdigit() and 0 < int(port) < 65536):
            raise InputError(f"invalid --coordinator {coord!r}; allowed: HOST:PORT of process 0, e.g. 10.0.0.1:12345")
        if n < 1:
            raise InputError(f"invalid --num-processes {n}; allowed: an int >= 1")
        if not 0 <= k < n:
            raise InputError(f"invalid --process-id {k}; allowed: 0..{n - 1} (--num-processes {n})")
        kwargs = {"coordinator_address": coord, "num_processes": n, "process_id": k}
    import jax

    try:
        jax.distributed.initialize(**kwargs)
    except (ValueError, RuntimeError) as e:
        how = ("the coordinator did not answer or the processes disagree" if kwargs
               else "no cluster found in the environment (SLURM, Open MPI)")
        raise InputError(f"invalid --distributed: jax.distributed.initialize failed ({how}: {e}); allowed: a "
                         "cluster environment or --coordinator HOST:PORT --num-processes N --process-id K") from None


def cmd_run(args) -> int:
    from .cases import build_problem
    from .simulation import run_problem

    if args.restart is not None:
        if args.overwrite:
            raise InputError(f"invalid --overwrite with --restart {args.restart}: overwriting deletes the run a "
                             "restart continues; allowed: one of them")
        if args.out is not None and Path(args.out).resolve() != Path(args.restart).resolve():
            raise InputError(f"invalid --out {args.out} with --restart {args.restart}: a restart writes into the "
                             "folder it continues; allowed: --restart DIR alone")
        from .checkpoint import read_checkpoint

        read_checkpoint(args.restart)   # a missing folder or checkpoint: say so before anything else
        cfg, stem = _load(args.config or str(Path(args.restart) / "config.toml"), args.set)
        out = Path(args.restart)
    else:
        cfg, stem = _load(args.config, args.set)
        out = Path(args.out) if args.out else Path("out") / stem
    problem = build_problem(cfg)
    try:
        with _fallback_lines():
            result = run_problem(problem, cfg, out_dir=out, quiet=args.quiet, overwrite=args.overwrite,
                                 restart=args.restart is not None)
    except SimulationError as e:
        print(f"mlsph: {e}\nmlsph: outputs (with the last good snapshot) are in {out}", file=sys.stderr)
        return 1
    except RunInterrupted as e:
        print(f"mlsph: {e}", file=sys.stderr)
        return 130
    if not args.quiet:
        print(result_paragraph(problem.description, result.summary, out))
    return 0


class _fallback_lines(warnings.catch_warnings):
    """Context manager: each :class:`DegreeFallbackWarning` of the run becomes one line
    ``mlsph: warning: ...`` on stderr (also when the run fails or is interrupted); other
    warnings are shown as usual."""

    def __init__(self):
        super().__init__(record=True)

    def __enter__(self):
        self._caught = super().__enter__()
        warnings.simplefilter("always", DegreeFallbackWarning)
        return self._caught

    def __exit__(self, *exc):
        super().__exit__(*exc)
        for w in self._caught:
            if issubclass(w.category, DegreeFallbackWarning):
                print(f"mlsph: warning: {w.message}", file=sys.stderr)
            else:
                warnings.showwarning(w.message, w.category, w.filename, w.lineno)


def result_paragraph(description: str, s: dict, out) -> str:
    """The one-paragraph result of ``mlsph run`` (every number as in summary.json)."""
    from .simulation import split_metrics

    errors, others = split_metrics(s["metrics"])
    fmt = lambda d: ", ".join(f"{k} = {v:.4g}" for k, v in d.items())
    info = s.get("conservation_info", {"label": "drift"})
    c = ", ".join(f"{k} {v:+.2e}" for k, v in s["conservation"].items())
    what = ("Relative drift of the totals (closed domain: round-off expected)" if info["label"] == "drift"
            else f"Relative {info['label']} of the totals (not errors; scales in summary.json)")
    return (f"{description}: {s['n_particles']} particles advanced to t = {s['t_final']:.6g} in "
            f"{s['n_steps']} SSP-RK3 steps ({s['wall_time_s']:.1f} s wall, "
            f"{s['compile_time_s']:.1f} s compiling, {s['particle_updates_per_s']:.3g} particle-updates/s). "
            f"Errors against the reference: {fmt(errors) or 'none'}."
            + (f" Other results: {fmt(others)}." if others else "")
            + f" {what}: {c}. "
            f"Outputs (summary.json, fields.h5 + fields.xmf for ParaView, config.toml, PNG plots) in {out}/.")


def _need_config(args) -> None:
    if args.config is None:
        raise ConfigError(f"mlsph {args.command}: missing CONFIG; allowed: a TOML file or a built-in config name "
                          "(mlsph cases lists them)")


def cmd_validate(args) -> int:
    _need_config(args)
    cfg, _ = _load(args.config, args.set)
    from .cases import build_problem

    build_problem(cfg)  # also checks what only the case builder can check
    print(f"{args.config}: ok (case {cfg['case']['name']}, eos {cfg['eos']['kind']}, "
          f"method {cfg['scheme']['method']})")
    return 0


def cmd_cases(args) -> int:
    from .cases import CASES
    from .config.builtin import CONFIG_DIR, builtin_configs, describe

    print("cases (case.name):")
    for name, case in CASES.items():
        print(f"  {name}: {case.doc}")
    print("\nbuilt-in configs (mlsph run NAME, mlsph init NAME):")
    for name in builtin_configs():
        print(f"  {name}: {describe(CONFIG_DIR / f'{name}.toml')}")
    return 0


def cmd_init(args) -> int:
    from . import config
    from .config.builtin import CONFIG_DIR, builtin_configs

    out = Path(args.out) if args.out else Path(f"{args.name}.toml")
    if out.exists():
        raise InputError(f"invalid --out {str(out)!r}: the file exists; allowed: a new file name (mlsph init does "
                         "not overwrite)")
    if args.name in builtin_configs():
        text = (CONFIG_DIR / f"{args.name}.toml").read_text()
    elif args.name in config.registered_cases():
        try:
            text = f"# Defaults of case {args.name!r} (mlsph init {args.name}); docs/config.md describes every key.\n" \
                   + config.dumps(config.load(None, case=args.name))
        except ConfigError:
            cfgs = [c for c in builtin_configs() if f'name = "{args.name}"' in (CONFIG_DIR / f"{c}.toml").read_text()]
            raise ConfigError(f"invalid CASE {args.name!r}: the case has required keys without defaults; allowed: "
                              f"one of its built-in configs ({', '.join(cfgs) or 'none'})") from None
    else:
        raise ConfigError(f"invalid CASE {args.name!r}; allowed: a built-in config ({', '.join(builtin_configs())}) "
                          f"or a case ({', '.join(config.registered_cases())})")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(f"wrote {out}; run it with: mlsph run {out}")
    return 0


def _diff_kw(args) -> dict:
    return {"n_steps": args.n_steps, "record_every": args.record_every, "checkpoint": args.checkpoint}


def _cfl_kw(cfg) -> dict:
    """The config's CFL numbers (time.cfl, time.cfl_viscous) for the differentiated runs' step checks."""
    t = cfg.get("time", {})
    if t.get("local_time_stepping", False):
        raise InputError("invalid time.local_time_stepping=true for a differentiated run: its fixed steps are one "
                         "dt for every particle; allowed: false (set it with --set time.local_time_stepping=false)")
    return {"cfl": t.get("cfl", 0.3), "cfl_viscous": t.get("cfl_viscous", 0.125)}


def cmd_sensitivity(args) -> int:
    import json

    from .cases import build_problem
    from .sensitivity import check_mode, sensitivity

    check_mode(args.mode)
    _need_config(args)
    cfg, stem = _load(args.config, args.set)
    problem = build_problem(cfg)
    t0 = time.perf_counter()
    # every forward run is checked (a failure raises SimulationError: exit 1; an --n-steps above the
    # CFL limit of time.cfl is refused before running: exit 2)
    res = sensitivity(problem, args.wrt, args.of, check_fd=args.check_fd, fd_rel=args.fd_rel, window=args.window,
                      mode=args.mode, **_cfl_kw(cfg), **_diff_kw(args))
    res["wall_time_s"] = time.perf_counter() - t0
    over = f" over t in [{res['window'][0]:.6g}, {res['window'][1]:.6g}]" if "window" in res else ""
    if "window" in res and args.window is None:
        print(_default_window_note(args.of, res["window"], cfg))
    print(f"{args.of} = {res['value']:.10g}{over} after {res['n_steps']} steps of dt = {res['dt']:.4g} "
          f"({res['mode']} mode)")
    for k, e in res["gradients"].items():
        line = f"  d {args.of} / d {k} = {e['gradient']}"
        if args.check_fd:
            line += (f"   (finite differences {e['fd']}, step {e['fd_step']}): AD and FD {e['verdict'].upper()}, "
                     f"relative difference {e['rel_difference']:.1e}")
            if e["hint"]:
                line += f"\n    hint: {e['hint']}"
        print(line)
    out = Path(args.out) if args.out else Path("out") / f"{stem}_sensitivity"
    out.mkdir(parents=True, exist_ok=True)
    (out / "sensitivity.json").write_text(json.dumps(res, indent=2))
    print(f"wrote {out / 'sensitivity.json'} ({res['wall_time_s']:.1f} s)")
    return 0


def _default_window_note(of: str, window, cfg) -> str:
    """The one line that says which window a time-averaged objective used when ``--window`` was
    not given: the whole run, start-up included (unlike statistics taken after a transient)."""
    transient = cfg["case"].get("transient")
    after = ("" if transient is None else
             f"; the case's summary.json statistics start after case.transient = {transient:g}")
    return (f"note: no --window given: {of} averages over the whole run, t in [{window[0]:.6g}, {window[1]:.6g}], "
            f"the start-up included{after}; --window T_START T_END excludes it")


def cmd_calibrate(args) -> int:
    from .cases import build_problem
    from .sensitivity import calibrate, check_mode, read_target, write_calibration

    check_mode(args.mode)
    _need_config(args)
    cfg, stem = _load(args.config, args.set)
    problem = build_problem(cfg)
    target = read_target(args.target)

    from tqdm.auto import tqdm

    def show(h):
        ps = ", ".join(f"{k} = {v}" for k, v in h["params"].items())
        tqdm.write(f"iteration {h['iteration']:4d}  loss {h['loss']:.6e}  {ps}")  # above the bar

    res = calibrate(problem, args.fit, target, steps=args.steps, lr=args.lr, progress=not args.quiet,
                    callback=show, optimizer=args.optimizer, tol=args.tol, mode=args.mode, **_cfl_kw(cfg),
                    **_diff_kw(args))
    out = Path(args.out) if args.out else Path("out") / f"{stem}_calibration"
    write_calibration(out, res)
    why = {"tol": f"loss <= --tol {args.tol}", "plateau": "the loss stopped decreasing",
           "steps": f"after --steps {args.steps}"}[res["stopped"]]
    ign = f"; target columns not recorded by the run, ignored: {', '.join(res['ignored_columns'])}" \
        if res["ignored_columns"] else ""
    print(f"fitted {res['final']} (loss {res['loss']:.3e}, stopped {why}; fitted to {', '.join(res['columns'])}{ign}); "
          f"wrote {out / 'history.json'} and {out / 'calibration.png'}")
    return 0


def load_plugins(plugins) -> None:
    """Import each ``--plugin``: a ``.py`` file (by path) or an importable module name, so that the
    components it registers can be named in the config (docs/extending.md)."""
    import importlib
    import importlib.util

    for plugin in plugins:
        if plugin.endswith(".py"):
            path = Path(plugin)
            if not path.is_file():
                raise ConfigError(f"invalid --plugin {plugin!r}: no such file; allowed: a Python file or an "
                                  "importable module name")
            name = f"mlsph_plugin_{path.stem}"
            spec = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            spec.loader.exec_module(module)
        else:
            try:
                importlib.import_module(plugin)
            except ModuleNotFoundError as e:
                raise ConfigError(f"invalid --plugin {plugin!r}: {e}; allowed: a Python file or an importable "
                                  "module name") from None


def _use_compilation_cache(option: str | None) -> None:
    """Turn on the persistent compilation cache for a command that compiles (module
    :mod:`mlsph_jax.compilation_cache`): a folder the user named must work (else an error naming
    the setting); the default folder that cannot be written (a read-only home) only costs the cache,
    with a warning."""
    chosen = option if option is not None else os.environ.get(compilation_cache.ENV)
    folder = compilation_cache.resolve(option)
    if folder is None:
        if chosen is not None and chosen.strip().lower() == compilation_cache.OFF:
            compilation_cache.disable()
        return
    if chosen is None or chosen == "":
        try:
            compilation_cache.enable(folder)
        except InputError:
            print(f"mlsph: warning: the default compilation cache folder {folder} cannot be written; running "
                  f"without the cache (choose a folder with --compilation-cache DIR or ${compilation_cache.ENV}, "
                  "or pass --compilation-cache off)", file=sys.stderr)
        return
    compilation_cache.enable(folder, name="--compilation-cache" if option is not None else compilation_cache.ENV)


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == "run":
            init_distributed(args)      # before a plugin or a config touches JAX's backends
        if hasattr(args, "compilation_cache"):     # the commands that compile (before any compilation)
            _use_compilation_cache(args.compilation_cache)
        load_plugins(getattr(args, "plugin", []))
        _fix_set(args)
        return {"run": cmd_run, "validate": cmd_validate, "cases": cmd_cases, "init": cmd_init,
                "sensitivity": cmd_sensitivity, "calibrate": cmd_calibrate}[args.command](args)
    except (ConfigError, InputError) as e:
        print(f"mlsph: error: {e}", file=sys.stderr)
        return 2
    except MLSPHError as e:
        print(f"mlsph: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:   # before or after a run's own interrupt handling (which writes the outputs)
        print("mlsph: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
