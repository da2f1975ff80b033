"""Where a Taylor-Green step spends its time: right-hand side, geometry, neighbour search and
the rest of the SSP-RK3 step, each compiled and timed on its own.

``taylor_green_2d`` (n x n, Re = 100, MLSPH-ALE degree 2, quadratic reconstruction) in the frames
of ``--frames``.  Timed (median of ``--repeat`` runs, each ahead-of-time compiled, jitted
functions of the public API):

* ``neighbors``: :func:`mlsph_jax.neighbors.update` (the list a moving run rebuilds per stage);
* ``geometry``:  :func:`mlsph_jax.rhs.geometry` (MLS area vectors and shape functions);
* ``rhs``:       :func:`mlsph_jax.rhs.rhs` with that geometry;
* ``step``:      :func:`mlsph_jax.integrate.ssp_rk3_step` (three stages; for moving particles
  each stage rebuilds the list and the geometry, :func:`mlsph_jax.integrate.make_stage_geometry`);
* ``rest`` = step - 3 rhs (Eulerian) or step - 3 (neighbors + geometry + rhs) (moving): the
  Shu-Osher combinations, limiter plumbing, frame velocity outside the right-hand side;
* ``chunk``:     the driver's jitted chunk (:func:`mlsph_jax.integrate.make_chunk`, fixed dt) of
  ``--chunk-steps`` steps, per step: CFL and status reductions included; for moving particles
  with the Verlet-skin lists (the driver's default) and, timed interleaved in the same process
  (best of ``--repeat``), with per-stage rebuilds (``skin = 0``); for Eulerian particles, timed
  interleaved with it, ``bare_rhs``: 3 x ``--chunk-steps`` bare forward-Euler sub-steps (right-hand
  side and update only), the bound of what the rest of the step (CFL and status reductions,
  Shu-Osher combinations, statistics) costs.

``--trace DIR`` also records a :mod:`jax.profiler` trace of five steps (open it with
TensorBoard's profile plugin or Perfetto).  ``--fusions N`` traces one run of the driver chunk
and prints its N most expensive XLA thunks (time per step summed over their calls, call count,
output shape and the source line of the jaxpr operation they come from; fusions inside the
blocked passes run once per row block): where a step's time goes, op by op; it also prints the
thunks executed per step inside the right-hand side and outside it, with their summed time.

    python experiments/profile_step.py --n 100 --frames eulerian ale_shift [--trace /tmp/trace]

Writes experiments/output/profile_step.json.  Not a test.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import jax
import numpy as np

from mlsph_jax import config
from mlsph_jax import neighbors as nb
from mlsph_jax.cases import build_problem
from mlsph_jax.integrate import StepControl, _euler, initial_carry, make_chunk, make_stage_geometry, ssp_rk3_step
from mlsph_jax.rhs import geometry, rhs
from mlsph_jax.run import setup_run, smoothing_lengths

OUT = Path(__file__).resolve().parents[1] / "experiments" / "output" / "profile_step.json"

BASE = '[case]\nname = "taylor_green_2d"\nre = 100.0\n[output]\nplots = false\nprogress = false\n'


def timed(f, *args, repeat: int) -> tuple[float, float]:
    """(compile seconds, median run seconds) of ``jax.jit(f)`` on ``args``."""
    t0 = time.perf_counter()
    c = jax.jit(f).lower(*args).compile()
    comp = time.perf_counter() - t0
    jax.block_until_ready(c(*args))
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(c(*args))
        runs.append(time.perf_counter() - t0)
    return comp, statistics.median(runs)


def interleaved(calls: dict, repeat: int) -> dict:
    """Best-of-``repeat`` time of each compiled call, the calls alternating (A B A B ...)."""
    best = dict.fromkeys(calls, float("inf"))
    for _ in range(repeat):
        for k, (f, args) in calls.items():
            t0 = time.perf_counter()
            jax.block_until_ready(f(*args))
            best[k] = min(best[k], time.perf_counter() - t0)
    return best


#: Source files of the right-hand side proper: a thunk whose call stack passes through one of
#: them is counted as right-hand side by :func:`thunk_table`'s split, every other one as the rest
#: of the step (CFL and status reductions, Shu-Osher combinations, statistics, loop plumbing).
RHS_FILES = ("rhs.py", "flux.py", "reconstruction.py", "viscous.py", "mls.py", "approximation/__init__.py",
             "stencil.py", "mood.py", "frames.py", "area_correction.py")


def thunk_table(compiled, args, steps: int, top: int, folder: str, split: dict | None = None) -> list[dict]:
    """The ``top`` most expensive XLA thunks of one call of ``compiled`` (a jax.profiler trace,
    events summed by name), with their HLO output shapes and source lines.  ``split`` (a dict)
    receives the thunks executed per step and their summed time, in the right-hand side (a
    source file of :data:`RHS_FILES` on the call stack) and outside it."""
    import glob
    import gzip
    import re
    from collections import Counter

    hlo = compiled.as_text()
    shape, where, in_rhs = {}, {}, {}
    names = hlo.split("\nFileNames\n", 1)[-1].split("\nFunctionNames\n", 1)[0]   # the FileNames section
    files = dict(re.findall(r'^(\d+) "[^"]*?([^"/]+)"$', names, re.M))
    paths = dict(re.findall(r'^(\d+) "([^"]*)"$', names, re.M))
    loc_file = {k: paths.get(f, "") for k, f in
                re.findall(r"^(\d+) \{file_name_id=(\d+) function_name_id=\d+ line=\d+", hlo, re.M)}
    parent = dict(re.findall(r"^(\d+) \{file_location_id=\d+ parent_frame_id=(\d+)", hlo, re.M))
    locs = {k: f"{files.get(f, '?')}:{ln}" for k, f, ln in
            re.findall(r"^(\d+) \{file_name_id=(\d+) function_name_id=\d+ line=(\d+)", hlo, re.M)}
    frames = dict(re.findall(r"^(\d+) \{file_location_id=(\d+) parent", hlo, re.M))
    for line in hlo.splitlines():
        m = re.match(r"\s*(?:ROOT )?%([\w.\-]+) = (.*)", line)
        if m:
            shape.setdefault(m.group(1), m.group(2).split(" fusion(")[0].split(" ")[0][:60])
            op = re.search(r'op_name="([^"]+)"', line)
            fr = re.search(r"stack_frame_id=(\d+)", line)
            if op:
                line_no = locs.get(frames.get(fr.group(1), ""), "?") if fr else "?"   # innermost frame
                where.setdefault(m.group(1), f"{op.group(1).split('/')[-1]} ({line_no})")
            if fr and m.group(1) not in in_rhs:      # any frame of the call stack in the rhs?
                fid, hit = fr.group(1), False
                for _ in range(200):
                    hit = hit or loc_file.get(frames.get(fid, ""), "").endswith(RHS_FILES)
                    if fid not in parent or parent[fid] == fid:
                        break
                    fid = parent[fid]
                in_rhs[m.group(1)] = hit
    jax.block_until_ready(compiled(*args))
    with jax.profiler.trace(folder, create_perfetto_trace=True):
        jax.block_until_ready(compiled(*args))
    f = sorted(glob.glob(f"{folder}/**/*.trace.json.gz", recursive=True))[-1]
    ev = json.load(gzip.open(f))
    ev = ev["traceEvents"] if isinstance(ev, dict) else ev
    tot, cnt = Counter(), Counter()
    for e in ev:
        if e.get("ph") == "X" and not e["name"].startswith(("while", "cond", "Thunk", "$", "call")):
            tot[e["name"]] += e.get("dur", 0)
            cnt[e["name"]] += 1
    if split is not None:           # thunks proper (not the trace's end markers or thread-pool events)
        for k in cnt:
            if k in shape:
                side = "rhs" if in_rhs.get(k) else "rest"
                split[f"{side}_thunks_per_step"] = split.get(f"{side}_thunks_per_step", 0.0) + cnt[k] / steps
                split[f"{side}_ms_per_step"] = split.get(f"{side}_ms_per_step", 0.0) + tot[k] / 1e3 / steps
    return [{"thunk": k, "ms_per_step": v / 1e3 / steps, "calls": cnt[k], "shape": shape.get(k, ""),
             "from": where.get(k, "")} for k, v in tot.most_common(top)]


def profile(n: int, frame: str, repeat: int, trace: str | None, chunk_steps: int = 10, calls=None,
            fusions: int = 0, sets=()) -> dict:
    cfg = config.loads(BASE, [f"case.n={n}", f"scheme.frame={frame}", "time.t_end=0.01", *sets])
    pb = build_problem(cfg)
    sc, dom, p, prm = pb.scheme, pb.domain, pb.particles, pb.params
    setup = setup_run(pb, headroom=cfg["scheme"]["neighbor_headroom"],
                      min_moving_headroom=cfg["scheme"]["moving_neighbor_headroom"] or True)
    h = jax.numpy.asarray(smoothing_lengths(p, sc))
    dt = 0.3 * (1.0 / n) / 11.0
    out = {"n": n, "particles": int(p.n), "frame": frame, "capacity": setup.nspec.capacity}
    _, out["neighbors_s"] = timed(lambda x, h: nb.update(x, h, setup.nspec), p.x, h, repeat=repeat)
    _, out["geometry_s"] = timed(lambda x, v, nl: geometry(x, v, nl, sc, dom), p.x, p.vol, setup.nl, repeat=repeat)
    g = jax.jit(lambda x, v, nl: geometry(x, v, nl, sc, dom))(p.x, p.vol, setup.nl)
    _, out["rhs_s"] = timed(lambda p, prm, g: rhs(p, prm, g, sc), p, prm, g, repeat=repeat)
    geom_fn = make_stage_geometry(sc, dom, setup.nspec) if sc.moving else None

    def step(p, prm, g):
        return ssp_rk3_step(p, prm, dt, sc, geom_fn if sc.moving else (lambda z: g))[0]

    out["step_compile_s"], out["step_s"] = timed(step, p, prm, g, repeat=repeat)
    per_stage = out["rhs_s"] + (out["neighbors_s"] + out["geometry_s"] if sc.moving else 0.0)
    out["rest_s"] = out["step_s"] - 3 * per_stage
    out["particle_steps_per_s"] = p.n / out["step_s"]
    own = {}
    for skin in ((0.3, 0.0) if sc.moving else (0.0,)):
        ch = make_chunk(sc, dom, StepControl(dt_fixed=dt), chunk_steps, nspec=setup.nspec if sc.moving else None,
                        skin=skin)
        args = (initial_carry(p), prm, None if sc.moving else g, jax.numpy.asarray(1e9))
        key = "chunk" if skin or not sc.moving else "chunk_rebuild"
        t0 = time.perf_counter()
        c = ch.lower(*args).compile()
        out[f"{key}_compile_s"] = time.perf_counter() - t0
        r = c(*args)
        assert int(r.status) == 0 and int(r.step) == chunk_steps, int(r.status)
        own[key] = (c, args)
    if not sc.moving:   # the bound of everything but the rhs: 3 x chunk_steps bare Euler sub-steps
        def bare(p, prm, g):
            return jax.lax.scan(lambda z, _: (_euler(z, jax.numpy.asarray(dt), rhs(z, prm, g, sc)), None), p, None,
                                length=3 * chunk_steps)[0]

        own["bare_rhs"] = (jax.jit(bare).lower(p, prm, g).compile(), (p, prm, g))
    for k, v in interleaved(own, repeat).items():
        out[f"{k}_step_s"] = v / chunk_steps
    out["chunk_particle_steps_per_s"] = p.n / out["chunk_step_s"]
    if calls is not None:          # for the interleaved timing of every frame's chunks (main)
        calls.update({(frame, k): (c, args, chunk_steps) for k, (c, args) in own.items()})
    if fusions:
        c, args = own["chunk"]
        split = {}
        out["thunks"] = thunk_table(c, args, chunk_steps, fusions, str(OUT.parent / f"trace_{frame}_{n}"), split)
        out["thunk_split"] = split
        print(f"{frame}: XLA thunks per step of the driver chunk: right-hand side "
              f"{split.get('rhs_thunks_per_step', 0):.1f} ({split.get('rhs_ms_per_step', 0):.2f} ms), rest "
              f"{split.get('rest_thunks_per_step', 0):.1f} ({split.get('rest_ms_per_step', 0):.2f} ms) "
              "(thunk time summed over one traced call)")
        print(f"{frame}: {fusions} most expensive XLA thunks of the driver chunk (ms per step, calls, output, "
              "operation (source line)):")
        for t in out["thunks"]:
            print(f"  {t['ms_per_step']:8.2f} {t['calls']:5d}  {t['shape']:40s} {t['from']}")
    if trace:
        c = jax.jit(step).lower(p, prm, g).compile()
        with jax.profiler.trace(str(Path(trace) / f"{frame}_{n}")):
            for _ in range(5):
                q = c(p, prm, g)
            jax.block_until_ready(q)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--frames", nargs="+", default=["eulerian", "ale_shift"])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--trace", default=None, help="folder for a jax.profiler trace of five steps")
    ap.add_argument("--chunk-steps", type=int, default=10, help="steps of the timed driver chunk")
    ap.add_argument("--fusions", type=int, default=0, help="print the N most expensive XLA thunks of the chunk")
    ap.add_argument("--set", nargs="*", default=[], dest="sets", help="config overrides KEY=VALUE (every frame)")
    a = ap.parse_args(argv)
    rows, calls = [], {}
    for frame in a.frames:
        r = profile(a.n, frame, a.repeat, a.trace, a.chunk_steps, calls, a.fusions, a.sets)
        rows.append(r)
        ms = {k: 1e3 * r[k] for k in ("neighbors_s", "geometry_s", "rhs_s", "step_s", "rest_s")}
        print(f"{frame:>9s} N={r['particles']}: step {ms['step_s']:.1f} ms = 3 x (rhs {ms['rhs_s']:.1f}"
              + (f" + neighbours {ms['neighbors_s']:.1f} + geometry {ms['geometry_s']:.1f}" if frame != "eulerian"
                 else "") + f") + rest {ms['rest_s']:.1f} ms; (geometry alone {ms['geometry_s']:.1f} ms, "
              f"neighbours alone {ms['neighbors_s']:.1f} ms); {r['particle_steps_per_s']:.3e} particle-steps/s",
              flush=True)
        print(f"{'':>9s} driver chunk: {1e3 * r['chunk_step_s']:.1f} ms/step "
              f"({r['chunk_particle_steps_per_s']:.3e} particle-steps/s, compile {r['chunk_compile_s']:.1f} s)"
              + (f"; per-stage rebuilds {1e3 * r['chunk_rebuild_step_s']:.1f} ms/step" if 'chunk_rebuild_step_s' in r
                 else "")
              + (f"; three bare rhs + Euler sub-steps {1e3 * r['bare_rhs_step_s']:.1f} ms/step (interleaved)"
                 if 'bare_rhs_step_s' in r else ""), flush=True)
    # every frame's chunks again, all interleaved in this process (A B C A B C ..., best of
    # --repeat): ratios that contention on a shared machine does not skew
    best = interleaved({k: (c, args) for k, (c, args, _) in calls.items()}, a.repeat)
    inter = {f"{fr}/{k}": best[(fr, k)] / calls[(fr, k)][2] for fr, k in calls}
    print("interleaved chunks, ms/step: " + ", ".join(f"{k} {1e3 * v:.1f}" for k, v in inter.items()), flush=True)
    if ("eulerian", "chunk") in calls:
        for fr in a.frames:
            if fr != "eulerian":
                ratio = inter[fr + "/chunk"] / inter["eulerian/chunk"]
                verl = (f"; per-stage rebuilds / Verlet: {inter[fr + '/chunk_rebuild'] / inter[fr + '/chunk']:.2f}"
                        if fr + "/chunk_rebuild" in inter else "")
                print(f"{fr} / eulerian chunk step (interleaved): {ratio:.2f}{verl}", flush=True)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    load = list(np.round(__import__("os").getloadavg(), 2))
    OUT.write_text(json.dumps({"rows": rows, "interleaved_chunk_step_s": inter, "load_average": load},
                              indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
