"""The library's plots leave matplotlib's global state alone (a notebook keeps its inline
backend after a run) and still write their PNG files."""

import matplotlib

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.simulation import run_problem


def test_a_run_with_plots_keeps_the_users_backend(tmp_path):
    before = matplotlib.get_backend()
    matplotlib.use("pdf")            # stands for a notebook's inline backend
    try:
        cfg = config.load("configs/riemann_r1_tait.toml", ["case.n=40", "time.t_end=2e-6", "output.progress=false"])
        run_problem(build_problem(cfg), cfg, out_dir=tmp_path)
        assert matplotlib.get_backend() == "pdf"
        png = tmp_path / "profiles.png"
        assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    finally:
        matplotlib.use(before)
