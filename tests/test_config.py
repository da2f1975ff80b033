"""Schema-validated TOML configs: defaults, errors, overrides, round trip, reference, case registry."""

from __future__ import annotations

import math
import tomllib

import pytest

from mlsph_jax import ConfigError, InputError
from mlsph_jax import config as C
from mlsph_jax.cases import CASES, build_problem, register_case
from mlsph_jax.registry import all_registries, registry
from mlsph_jax.schema import Key
from mlsph_jax.testing import CONFIG_DIR, builtin_configs

SOD = """
[case]
name = "riemann_1d"
left = {rho = 1.0, u = 0.0, p = 1.0}
right = {rho = 0.125, u = 0.0, p = 0.1}
x_interface = 0.5
domain = [0.0, 1]
n = 200

[time]
t_end = 0.2
"""

R1_TAIT = """
[case]
name = "riemann_1d"
left = {rho = 1100, u = 0}
right = {rho = 1000, u = 0}
x_interface = 0.05
domain = [0, 0.1]
n = 100

[eos]
kind = "tait"
rho0 = 1000
c0 = 1466.0

[time]
t_end = 1e-5
"""


def _with(text: str, table: str, line: str) -> str:
    """Insert ``line`` at the top of ``[table]`` (adding the table if absent)."""
    if f"[{table}]\n" in text:
        return text.replace(f"[{table}]\n", f"[{table}]\n{line}\n", 1)
    return text + f"\n[{table}]\n{line}\n"


@pytest.fixture
def scratch_registry(monkeypatch):
    """Cases registered by a test disappear after it (other tests see the real ones)."""
    monkeypatch.setattr(CASES, "_items", dict(CASES._items))


def _no_build(cfg):
    raise AssertionError("not built in this test")


def _err(text: str, overrides=()) -> str:
    with pytest.raises(ConfigError) as e:
        C.loads(text, overrides)
    return str(e.value)


# -- defaults ---------------------------------------------------------------------------------

def test_defaults_filled():
    cfg = C.loads(SOD)
    assert list(cfg) == list(C.TABLES)
    for table, schema in C.SCHEMA_COMMON.items():
        assert list(cfg[table]) == list(schema)
    s = cfg["scheme"]
    assert (s["method"], s["approximation"], s["degree"], s["kernel"]) == (
        "mlsph_ale", "mls", 2, "cubic_spline")
    assert s["beta"] == 0.0 and C.effective_beta(s) == 1.5
    assert C.effective_beta({**s, "method": "sph_ale"}) == 2.0
    assert C.effective_beta({**s, "beta": 1.2}) == 1.2
    # riemann_1d overrides the frame default: the thesis plots R1/R2 Lagrangian
    assert s["self_flux"] is True and s["frame"] == "lagrangian" and s["limiter"] == "none"
    assert s["neighbor_headroom"] == 1.3 and s["reconstruction_degree"] == 2
    assert cfg["time"] == {"t_end": 0.2, "cfl": 0.3, "dt": 0.0, "max_steps": 1_000_000,
                           "chunk": 50, "dt_min": 1e-14, "cfl_viscous": 0.125, "local_time_stepping": False,
                           "local_step_ratio": 4.0}
    assert cfg["output"] == {"snapshots": 10, "series_interval": 0.0, "plots": True, "progress": True,
                             "degree_fallback_warn": 0.01}
    assert cfg["physics"] == {"mu": 0.0, "kappa": 0.0, "body_force": []}
    assert cfg["eos"] == {"kind": "ideal_gas", "gamma": 1.4}
    assert cfg["case"]["domain"] == [0.0, 1.0] and isinstance(cfg["case"]["domain"][1], float)
    assert cfg["case"]["n"] == 200 and isinstance(cfg["case"]["n"], int)


def test_ints_converted_for_float_keys_and_validate_idempotent():
    cfg = C.loads(R1_TAIT)
    assert cfg["eos"] == {"kind": "tait", "rho0": 1000.0, "c0": 1466.0, "gamma": 7.0, "p0": 0.0}
    assert all(type(v) is float for v in cfg["case"]["left"].values())
    assert C.validate(cfg) == cfg


def test_defaults_only_config_needs_required_keys_from_overrides():
    msg = str(pytest.raises(ConfigError, C.load, None, case="riemann_1d").value)
    for k in ("case.left", "case.right", "case.x_interface", "case.domain", "case.n", "time.t_end"):
        assert k in msg
    cfg = C.load(None, case="riemann_1d", overrides=[
        "time.t_end=0.2", "case.left={rho=1, u=0, p=1}", "case.right.rho=0.125",
        "case.right.u=0", "case.right.p=0.1", "case.x_interface=0.5", "case.domain=[0, 1]",
        "case.n=200"])
    assert cfg == C.loads(SOD)
    with pytest.raises(ConfigError, match="case"):
        C.load(None)


def test_case_argument_must_match_file(tmp_path, scratch_registry):
    p = tmp_path / "sod.toml"
    p.write_text(SOD)
    assert C.load(p, case="riemann_1d") == C.load(p)
    register_case("dummy_case_for_tests", {"size": Key(int, 3, minimum=1)}, _no_build)
    with pytest.raises(ConfigError, match="dummy_case_for_tests"):
        C.load(p, case="dummy_case_for_tests")
    cfg = C.load(None, case="dummy_case_for_tests", overrides=["time.t_end=1"])
    assert cfg["case"] == {"name": "dummy_case_for_tests", "size": 3}


# -- unknown keys and tables ------------------------------------------------------------------

def test_unknown_key_named_with_suggestion_and_valid_keys():
    msg = _err(_with(SOD, "scheme", "reconstruction_degre = 1"))
    assert "scheme.reconstruction_degre" in msg
    assert "did you mean scheme.reconstruction_degree?" in msg
    assert "valid keys of [scheme]:" in msg and "neighbor_headroom" in msg


def test_unknown_table_and_top_level_key():
    msg = _err(SOD + "\n[schme]\ndegree = 1\n")
    assert "unknown table [schme]" in msg and "did you mean [scheme]?" in msg
    msg = _err("cfl = 0.5\n" + SOD)
    assert "unknown top-level key cfl" in msg and "did you mean time.cfl?" in msg


def test_all_problems_reported_together():
    text = _with(_with(SOD, "scheme", "degree = 1.0"), "time", "cfl = 2")
    msg = _err(_with(text, "output", "plot = false"))
    assert msg.startswith("3 problems")
    assert "scheme.degree" in msg and "time.cfl" in msg and "output.plot" in msg


# -- types ------------------------------------------------------------------------------------

@pytest.mark.parametrize("table, line, key, value, why", [
    ("scheme", "degree = 1.0", "scheme.degree", "1.0", "expected int, got float"),
    ("scheme", "degree = true", "scheme.degree", "true", "expected int, got bool"),
    ("time", 'cfl = "0.3"', "time.cfl", '"0.3"', "expected float, got str"),
    ("time", "cfl = true", "time.cfl", "true", "expected float, got bool"),
    ("scheme", "self_flux = 1", "scheme.self_flux", "1", "expected bool"),
    ("scheme", "method = 1", "scheme.method", "1", "expected str, got int"),
    ("physics", "body_force = 9.81", "physics.body_force", "9.81", "expected list of float"),
    ("physics", 'body_force = [0.0, "g"]', "physics.body_force", '[0.0, "g"]', "item 1"),
    ("time", "dt = inf", "time.dt", "inf", "finite"),
    ("time", "cfl = nan", "time.cfl", "nan", "finite"),
])
def test_wrong_types(table, line, key, value, why):
    msg = _err(_with(SOD, table, line))
    assert f"invalid {key}={value}" in msg and why in msg and "allowed:" in msg


# -- ranges and choices -----------------------------------------------------------------------

@pytest.mark.parametrize("table, line, key, allowed", [
    ("scheme", "degree = 4", "scheme.degree", "int in [0, 3]"),
    ("scheme", "reconstruction_degree = -1", "scheme.reconstruction_degree", "int in [0, 3]"),
    ("scheme", "beta = -1.0", "scheme.beta", "float >= 0.0"),
    ("scheme", "neighbor_headroom = 0.9", "scheme.neighbor_headroom", "float >= 1.0"),
    ("scheme", "wall_rcond = 1.0", "scheme.wall_rcond", "float in [0.0, 1.0)"),
    ("scheme", "wall_rcond = -0.1", "scheme.wall_rcond", "float in [0.0, 1.0)"),
    ("time", "cfl = 0", "time.cfl", "float in (0.0, 1.0]"),
    ("time", "cfl = 1.5", "time.cfl", "float in (0.0, 1.0]"),
    ("time", "max_steps = 0", "time.max_steps", "int >= 1"),
    ("time", "dt = -1e-6", "time.dt", "float >= 0.0"),
    ("output", "snapshots = 0", "output.snapshots", "int >= 1"),
    ("physics", "mu = -0.1", "physics.mu", "float >= 0.0"),
    ("eos", "gamma = 1.0", "eos.gamma", "float > 1.0"),
    ("case", "n = 9", "case.n", "int >= 10"),
    ("scheme", 'kernel = "gaussian"', "scheme.kernel", 'one of "cubic_spline"'),
    ("scheme", 'frame = "ale"', "scheme.frame", 'one of "ale_shift", "eulerian", "lagrangian"'),
])
def test_range_and_choice_errors(table, line, key, allowed):
    text = SOD.replace("n = 200\n", "") if key == "case.n" else SOD
    msg = _err(_with(text, table, line))
    assert f"invalid {key}=" in msg and f"allowed: {allowed}" in msg


@pytest.mark.parametrize("value", [1.0, -0.1, float("nan"), "0.1", True])
def test_scheme_wall_rcond_checked_in_the_api(value):
    """The threshold of truncated stencils (decision 77) built without a config file: a clear
    InputError naming the key, the value and the allowed range."""
    from mlsph_jax.scheme import Scheme

    with pytest.raises(InputError, match=r"scheme\.wall_rcond=.*allowed: a float with 0 <= wall_rcond < 1"):
        Scheme(wall_rcond=value)


def test_fixed_length_list_and_body_force_dimension():
    msg = _err(SOD.replace("domain = [0.0, 1]", "domain = [0.0, 0.5, 1.0]"))
    assert "case.domain" in msg and "expected 2 items" in msg
    msg = _err(_with(SOD, "physics", "body_force = [0.0, -9.81]"))
    assert "physics.body_force" in msg and "1-D" in msg
    assert C.loads(_with(SOD, "physics", "body_force = [-1]"))["physics"]["body_force"] == [-1.0]


# -- overrides --------------------------------------------------------------------------------

@pytest.mark.parametrize("s, expected", [
    ("scheme.reconstruction_degree=1", ("scheme.reconstruction_degree", 1)),
    ("time.t_end=1e-5", ("time.t_end", 1e-5)),
    ("time.cfl = 0.25", ("time.cfl", 0.25)),
    ("time.cfl=.5", ("time.cfl", 0.5)),
    ("time.t_end=2", ("time.t_end", 2.0)),
    ("scheme.self_flux=false", ("scheme.self_flux", False)),
    ("output.plots=True", ("output.plots", True)),
    ("scheme.method=sph_ale", ("scheme.method", "sph_ale")),
    ('scheme.kernel="wendland_c2"', ("scheme.kernel", "wendland_c2")),
    ("physics.body_force=[0.0, -9.81]", ("physics.body_force", [0.0, -9.81])),
    ("physics.body_force=[]", ("physics.body_force", [])),
    ("case.domain=[0, 1]", ("case.domain", [0.0, 1.0])),
    ("case.left={rho=1, u=0}", ("case.left", {"rho": 1.0, "u": 0.0})),
    ("case.left.p=1e5", ("case.left.p", 1e5)),
    ("eos.kind=tait", ("eos.kind", "tait")),
    ("eos.rho0=1000", ("eos.rho0", 1000.0)),
])
def test_parse_override(s, expected):
    key, value = C.parse_override(s)
    assert (key, value) == expected
    assert type(value) is type(expected[1])


@pytest.mark.parametrize("s, fragment", [
    ("scheme.degree", "KEY=VALUE"),
    ("scheme.degre=1", "did you mean scheme.degree?"),
    ("schem.degree=1", "did you mean scheme.degree?"),
    ("degree=1", "TABLE.KEY"),
    ("scheme.degree=1.5", "expected int, got float"),
    ("scheme.degree=two", "not a valid TOML value"),
    ("scheme.degree=7", "out of range"),
    ("scheme.self_flux=1", "expected bool"),
    ("time.cfl=fast", "not a number"),
    ("time.cfl=inf", "finite"),
    ("time.t_end=1\nx=2", "line breaks"),
    ("physics.body_force=[0, 'a']", "item 1"),
    ("scheme.method=other", "one of"),
    ("scheme.degree.x=1", "not a table"),
    ("case.left.rho=abc", "not a number"),
])
def test_parse_override_errors(s, fragment):
    with pytest.raises(ConfigError) as e:
        C.parse_override(s)
    assert fragment in str(e.value)


def test_overrides_applied_before_validation():
    cfg = C.loads(SOD, ["scheme.degree=1", "output.plots=false", "time.t_end=0.1",
                        "physics.mu=1e-3", "case.left.p=2"])
    assert cfg["scheme"]["degree"] == 1 and cfg["output"]["plots"] is False
    assert cfg["time"]["t_end"] == 0.1 and cfg["physics"]["mu"] == 1e-3
    assert cfg["case"]["left"] == {"rho": 1.0, "u": 0.0, "p": 2.0}
    # the EOS override selects the schema the other overrides are checked against
    cfg = C.loads(R1_TAIT.replace('kind = "tait"\nrho0 = 1000\nc0 = 1466.0\n', ""),
                  ["eos.c0=1466", "eos.kind=tait", "eos.rho0=1000"])
    assert cfg["eos"]["kind"] == "tait" and cfg["eos"]["c0"] == 1466.0
    msg = _err(SOD, ["eos.rho0=1000"])
    assert "eos.rho0" in msg and "tait" in msg  # belongs to another kind
    msg = _err(SOD, ["scheme.no_such_key=1"])
    assert "unknown key scheme.no_such_key" in msg


# -- EOS --------------------------------------------------------------------------------------

def test_eos_specific_keys():
    msg = _err(R1_TAIT.replace("rho0 = 1000\nc0 = 1466.0\n", ""))
    assert "eos.rho0" in msg and "eos.c0" in msg and "missing required keys" in msg
    msg = _err(_with(SOD, "eos", 'kind = "water"'))
    assert "invalid eos.kind=\"water\"" in msg
    for kind in ("ideal_gas", "tait", "stiffened_gas"):
        assert kind in msg
    msg = _err(_with(SOD, "eos", "rho0 = 1000.0"))
    assert "unknown key eos.rho0" in msg and "valid keys of [eos] with kind = 'ideal_gas'" in msg
    text = _with(SOD, "eos", 'kind = "stiffened_gas"\ngamma = 7.15\npc = 3e8')
    assert C.loads(text)["eos"] == {"kind": "stiffened_gas", "gamma": 7.15, "pc": 3e8}
    assert "eos.pc" in _err(_with(SOD, "eos", 'kind = "stiffened_gas"\ngamma = 7.15'))
    # heat conduction needs an energy equation: not silently ignored for the barotropic Tait EOS
    msg = _err(R1_TAIT, ["physics.kappa=0.5"])
    assert "invalid physics.kappa=0.5" in msg and "tait" in msg and "allowed: 0" in msg
    assert C.loads(SOD, ["physics.kappa=0.5"])["physics"]["kappa"] == 0.5


# -- case selection and riemann_1d cross-checks -----------------------------------------------

def test_case_name_required_and_registered():
    msg = _err(SOD.replace('name = "riemann_1d"\n', ""))
    assert "missing required key case.name" in msg and "riemann_1d" in msg
    msg = _err(SOD.replace('name = "riemann_1d"', 'name = "riemann_2d"'))
    assert 'invalid case.name="riemann_2d"' in msg and "riemann_1d" in msg
    msg = _err(_with(SOD, "case", "xinterface = 0.5"))
    assert "did you mean case.x_interface?" in msg and "of case 'riemann_1d'" in msg


@pytest.mark.parametrize("text, fragment", [
    (SOD.replace("x_interface = 0.5", "x_interface = 1.5"), "case.x_interface=1.5: outside"),
    (SOD.replace("x_interface = 0.5", "x_interface = 0.0"), "case.x_interface=0.0: outside"),
    (SOD.replace("domain = [0.0, 1]", "domain = [1.0, 0.0]"), "case.domain=[1.0, 0.0]"),
    (SOD.replace(", p = 0.1}", "}"), "missing required key case.right.p"),
    (SOD.replace("p = 1.0}", "p = -1.0}"), "case.left.p=-1.0: out of range"),
    (SOD.replace("rho = 0.125", "rho = 0.0"), "case.right.rho=0.0"),
    (SOD.replace("u = 0.0, p = 1.0", "v = 0.0, p = 1.0"), "unknown key case.left.v"),
    (R1_TAIT.replace("u = 0}", "u = 0, p = 2.9e8}"),
     "case.left.p=290000000.0: the pressure follows from rho for the barotropic Tait EOS"),
])
def test_riemann_1d_cross_checks(text, fragment):
    assert fragment in _err(text)


def test_riemann_1d_stiffened_gas_pressure_bound():
    text = _with(SOD, "eos", 'kind = "stiffened_gas"\ngamma = 7.15\npc = 3e8')
    assert C.loads(text.replace("p = 0.1}", "p = -1e8}"))["case"]["right"]["p"] == -1e8
    assert "p > -pc" in _err(text.replace("p = 0.1}", "p = -4e8}"))


# -- registration -----------------------------------------------------------------------------

def test_register_case_defaults_override_and_check(scratch_registry):
    def check(cfg):
        """Width must exceed height."""
        if cfg["case"]["width"] <= cfg["case"]["height"]:
            raise ConfigError("invalid case.width: must exceed case.height")

    case = register_case(
        "dummy_box_for_tests", {"width": Key(float, 2.0, minimum=0.0, doc="box width"),
                                "height": Key(float, 1.0, doc="box height")}, _no_build,
        defaults_override={"scheme.frame": "lagrangian", "time.t_end": 1e-5, "eos.kind": "tait",
                           "eos.rho0": 1000, "eos.c0": 10},
        check=check, dim=2, doc="A box for the tests.")
    assert CASES.get("dummy_box_for_tests") is case and case.defaults_override["eos.rho0"] == 1000.0
    cfg = C.load(None, case="dummy_box_for_tests")
    assert cfg["scheme"]["frame"] == "lagrangian" and cfg["time"]["t_end"] == 1e-5
    assert cfg["eos"] == {"kind": "tait", "rho0": 1000.0, "c0": 10.0, "gamma": 7.0, "p0": 0.0}
    # per-case eos defaults apply only to the kind that has the key
    cfg = C.load(None, case="dummy_box_for_tests", overrides=["eos.kind=ideal_gas"])
    assert cfg["eos"] == {"kind": "ideal_gas", "gamma": 1.4}
    cfg = C.load(None, case="dummy_box_for_tests", overrides=["physics.body_force=[0, -9.81]"])
    assert cfg["physics"]["body_force"] == [0.0, -9.81]
    with pytest.raises(ConfigError, match="must exceed"):
        C.load(None, case="dummy_box_for_tests", overrides=["case.width=0.5"])
    with pytest.raises(InputError, match="unknown key 'scheme.nope'"):
        register_case("dummy_bad_for_tests", {}, _no_build, defaults_override={"scheme.nope": 1})
    with pytest.raises(ConfigError, match="scheme.degree"):
        register_case("dummy_bad_for_tests", {}, _no_build, defaults_override={"scheme.degree": 9})
    with pytest.raises(ConfigError, match="scheme.frame"):
        register_case("dummy_bad_for_tests", {}, _no_build, defaults_override={"scheme.frame": "nope"})
    with pytest.raises(InputError, match="added automatically"):
        register_case("dummy_bad_for_tests", {"name": Key(str, "x")}, _no_build)
    with pytest.raises(InputError, match="must be a Key"):
        register_case("dummy_bad_for_tests", {"n": 3}, _no_build)
    with pytest.raises(InputError, match="build"):
        register_case("dummy_bad_for_tests", {}, None)
    with pytest.raises(InputError, match="dim"):
        register_case("dummy_bad_for_tests", {}, _no_build, dim=4)
    with pytest.raises(InputError, match="Bad_Name"):
        register_case("Bad_Name", {}, _no_build)
    assert "dummy_bad_for_tests" not in CASES
    with pytest.raises(ConfigError, match="<default>"):
        Key(int, 1.5)


def test_registering_a_case_twice_names_the_kind_the_name_and_the_registered_names(scratch_registry):
    register_case("dummy_twice_for_tests", {}, _no_build)
    with pytest.raises(InputError) as e:
        register_case("dummy_twice_for_tests", {}, _no_build)
    msg = str(e.value)
    assert "case.name" in msg and "'dummy_twice_for_tests'" in msg and "registered already" in msg
    for name in ("riemann_1d", "couette", "dummy_twice_for_tests"):
        assert name in msg
    # replace=True is the way to register it again (a notebook cell run twice)
    again = register_case("dummy_twice_for_tests", {"n": Key(int, 1)}, _no_build, replace=True)
    assert CASES.get("dummy_twice_for_tests") is again


def test_user_case_selected_by_name_in_a_toml_config(scratch_registry):
    """A script registers a case (keys, check, builder) and a TOML config runs it by name."""
    built = {}

    def build(cfg):
        built["n"] = cfg["case"]["n"]
        return CASES.get("riemann_1d").build(C.loads(SOD, [f"case.n={cfg['case']['n']}"]))

    def check(cfg):
        """`n` must be even."""
        if cfg["case"]["n"] % 2:
            raise ConfigError(f"invalid case.n={cfg['case']['n']}: odd; allowed: an even int")

    register_case("my_tube_for_tests", {"n": Key(int, 20, minimum=10, doc="particles")}, build, check=check,
                  dim=1, doc="A Sod tube registered by a test.", defaults_override={"time.t_end": 0.1})
    text = '[case]\nname = "my_tube_for_tests"\nn = 30\n\n[scheme]\nflux = "rusanov"\n'
    cfg = C.loads(text)
    assert cfg["case"] == {"name": "my_tube_for_tests", "n": 30} and cfg["time"]["t_end"] == 0.1
    problem = build_problem(cfg)
    assert built == {"n": 30} and problem.particles.x.shape[0] > 30
    assert "odd" in _err(text.replace("n = 30", "n = 31"))
    assert "unknown key case.m" in _err(text.replace("n = 30", "m = 30"))
    md = C.config_reference_markdown()
    assert 'case.name = "my_tube_for_tests"' in md and "A Sod tube registered by a test." in md
    assert "`n` must be even." in md


def test_unregistered_component_names_the_key_the_value_and_the_registered_names():
    msg = _err(_with(SOD, "scheme", 'flux = "nope"'))
    assert 'invalid scheme.flux="nope"' in msg and "not a registered name" in msg
    assert "allowed: one of " in msg and all(f'"{n}"' in msg for n in registry("scheme.flux").names())
    msg = _err(_with(SOD, "scheme", 'kernel = "cubic_splin"'))
    assert 'did you mean "cubic_spline"?' in msg
    for key, kind in [("limiter", "scheme.limiter"), ("frame", "scheme.frame"), ("method", "scheme.method")]:
        msg = _err(_with(SOD, "scheme", f'{key} = "nope"'))
        assert f'invalid scheme.{key}="nope"' in msg
        assert all(f'"{n}"' in msg for n in registry(kind).names())
    msg = _err(SOD, ['scheme.mood_variables=["rho", "nope"]'])
    assert "scheme.mood_variables" in msg and '"nope"' in msg and '"vel"' in msg
    msg = _err(SOD, ["eos.kind=nope"])
    assert 'invalid eos.kind="nope"' in msg and all(k in msg for k in registry("eos.kind").names())


def test_component_keys_follow_their_registries(monkeypatch):
    """Allowed names of component keys are read from the registries, at check time."""
    component_keys = {k: key for k, key in C.SCHEMA_COMMON["scheme"].items() if key.registered}
    assert set(component_keys) == {
        "method", "approximation", "kernel", "reconstruction", "reconstruction_variables", "flux", "wave_speed",
        "dissipation_normal", "frame", "shift_law", "stress", "position_update", "limiter", "mood_delta_floor",
        "mood_variables", "low_mach_reconstruction", "parachute_flux", "area_correction"}
    assert not C.SCHEMA_COMMON["scheme"]["derivative"].registered  # a plain choice, not a component
    kinds = all_registries()
    # the parachute flux: "same" or any registered flux
    assert list(component_keys.pop("parachute_flux").choice_names()) == ["same", *kinds["scheme.flux"].names()]
    for k, key in component_keys.items():
        names = kinds[f"scheme.{k}"].names()
        assert list(key.choice_names()) == names
        default = key.default if isinstance(key.default, list) else [key.default]
        assert set(default) <= set(names), f"default of scheme.{k} is registered"
    assert list(C.EOS_KIND.choice_names()) == kinds["eos.kind"].names() and C.EOS_KIND.default in kinds["eos.kind"]
    assert list(C.CASE_NAME.choice_names()) == kinds["case.name"].names()
    # a newly registered component is accepted at once (a fake flux: only its name matters here)
    flux = registry("scheme.flux")
    monkeypatch.setattr(flux, "_items", {**flux._items, "my_flux": flux.get("rusanov")})
    assert C.loads(_with(SOD, "scheme", 'flux = "my_flux"'))["scheme"]["flux"] == "my_flux"


def test_eos_tables_match_the_eos_registry():
    eos = registry("eos.kind")
    assert set(C.EOS_SCHEMAS) == set(eos.names())
    for kind, keys in C.EOS_SCHEMAS.items():
        assert {f"eos.{k}" for k in keys} == set(eos.get(kind).params_keys), kind


def test_eos_registered_from_a_script_gets_config_keys_from_its_params(monkeypatch):
    """A user's EOS needs no config edit: its [eos] keys are its ``eos.*`` params (floats), with its
    defaults where given."""
    eos = registry("eos.kind")
    tait = eos.get("tait")
    mine = type(tait)("my_eos_for_tests", False, ("eos.c0", "eos.rho0"), pressure=tait.pressure,
                      sound_speed=tait.sound_speed, internal_energy=tait.internal_energy, defaults={"eos.c0": 2.0})
    monkeypatch.setattr(eos, "_items", {**eos._items, "my_eos_for_tests": mine})
    text = R1_TAIT.replace('kind = "tait"\nrho0 = 1000\nc0 = 1466.0\n', 'kind = "my_eos_for_tests"\nrho0 = 1000\n')
    assert C.loads(text)["eos"] == {"kind": "my_eos_for_tests", "c0": 2.0, "rho0": 1000.0}
    msg = _err(text.replace("rho0 = 1000\n", ""))
    assert "missing required key: eos.rho0" in msg
    msg = _err(text.replace("rho0 = 1000\n", "rho0 = 1000\ngamma = 7\n"))
    assert "unknown key eos.gamma" in msg and "kind = 'my_eos_for_tests'" in msg
    assert '### `eos.kind = "my_eos_for_tests"`' in C.config_reference_markdown()


def test_effective_beta_is_the_method_default():
    from mlsph_jax.scheme import default_beta

    s = C.loads(SOD)["scheme"]
    for method in registry("scheme.method").names():
        assert C.effective_beta({**s, "method": method}) == default_beta(method)
    assert C.effective_beta({**s, "beta": 1.2}) == 1.2


# -- TOML writer and round trip ---------------------------------------------------------------

def test_dumps_loads_round_trip_of_every_builtin_config():
    assert len(builtin_configs()) >= 9
    for stem in builtin_configs():
        cfg = C.load(CONFIG_DIR / f"{stem}.toml")
        assert C.loads(C.dumps(cfg)) == cfg, stem


@pytest.mark.parametrize("text", [SOD, R1_TAIT])
def test_dumps_load_round_trip(tmp_path, text):
    cfg = C.loads(text, ["physics.body_force=[-9.81]", "time.dt_min=1e-300"])
    out = C.dumps(cfg)
    assert tomllib.loads(out) == cfg
    p = tmp_path / "resolved.toml"
    p.write_text(out)
    assert C.load(p) == cfg


def test_dumps_value_types():
    doc = {
        "top": 1,
        "t": {"s": 'quote " back \\ tab \t nl \n bell \x07 é', "i": -(2**63), "f": 1e-300,
              "g": -0.0, "h": 1.5e300, "big": 123456789.125, "b": False, "empty": [],
              "nums": [1, 2.5, -3e-7], "strs": ["a", "b c"], "inline": {"rho": 1.0, "u": -2},
              "weird key": 1, "nested": {"deeper": {"x": 1}, "y": 2}},
        "empty_table": {},
    }
    back = tomllib.loads(C.dumps(doc))
    assert back == doc
    assert all(type(a) is type(b) for a, b in zip(back["t"]["nums"], doc["t"]["nums"], strict=True))
    assert math.copysign(1.0, back["t"]["g"]) == -1.0
    with pytest.raises(ConfigError, match="t.f"):
        C.dumps({"t": {"f": float("inf")}})
    with pytest.raises(ConfigError, match="finite"):
        C.dumps({"t": {"l": [1.0, float("nan")]}})
    with pytest.raises(ConfigError, match="None"):
        C.dumps({"t": {"n": None}})


# -- reference documentation ------------------------------------------------------------------

def test_reference_markdown_mentions_every_key():
    md = C.config_reference_markdown()
    for table, schema in C.SCHEMA_COMMON.items():
        for k in schema:
            assert f"`{table}.{k}`" in md
    for kind, schema in C.EOS_SCHEMAS.items():
        assert f'eos.kind = "{kind}"' in md
        for k in schema:
            assert f"`eos.{k}`" in md
    assert "`eos.kind`" in md and "`case.name`" in md
    for name, case in CASES.items():
        assert f'case.name = "{name}"' in md and case.doc in md
        assert "SPEC" not in case.doc and "thesis" in case.doc
        for k in case.keys:
            assert f"`case.{k}`" in md
    assert "| `time.t_end` | float | **required** | float > 0.0 | final physical time [s] |" in md
    assert "barotropic tait EOS" in md  # the riemann_1d cross-checks are documented
    # allowed names of component keys are the registered ones
    assert '| one of "ale_shift", "eulerian", "lagrangian" |' in md
    assert ('one of "blast_2d", "couette", "cylinder", "lid_driven_cavity", "poiseuille", "riemann_1d", '
            '"taylor_green_2d"') in md
    for key in C.SCHEMA_COMMON["scheme"].values():
        assert key.doc, "every key has a doc line"
