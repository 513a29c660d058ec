"""Contact laws by name: the registry, the composition, and the capillary bridge against its closed
form (Willett et al. 2000, Lian, Thornton & Adams 1993)."""

import math

import numpy as np
import pytest
from scipy.integrate import quad

from calib_cli.dem.forces import evaluate_contact
from calib_cli.dem.laws import FAMILIES, REGISTRY, ContactModel
from calib_cli.dem.laws.capillary import BRIDGE
from calib_cli.dem.laws.columns import HIST
from calib_cli.dem.materials import Interaction, Material, contact_model, param_row
from calib_cli.dem.system import Particles, System, Walls
from calib_cli.errors import CalibError

R = 2e-3
MAT = Material(5e6, 0.25, 2600.0)
GAMMA_L, THETA, PHI = 0.072, 20.0, 0.01
WET = Interaction(0.0, 0.0, 1.0, 0.0, surface_tension=GAMMA_L, contact_angle=THETA, liquid_volume=PHI)
SPEC = ContactModel(cohesion="capillary").spec
#: the closed forms' own quantities for two equal grains of radius R (Derjaguin radius R)
V_BRIDGE = PHI * 4 / 3 * math.pi * R**3
F0 = 2 * math.pi * R * GAMMA_L * math.cos(math.radians(THETA))
S_RUPTURE = (1 + math.radians(THETA) / 2) * V_BRIDGE ** (1 / 3)


def willett(S):
    """Willett et al. (2000) Eqs. 12-13 with S+ = (S/2) sqrt(R/V)."""
    sp = S / 2 * math.sqrt(R / V_BRIDGE)
    return -F0 / (1 + 2.1 * sp + 10 * sp * sp)


def _normal_force(delta, ht, it=WET, spec=SPEC):
    """The normal force on i of a pair of equal grains at overlap delta (n = +x, at rest)."""
    prm = np.vstack([param_row(MAT, MAT, it)] * 3)
    m = 4 / 3 * math.pi * R**3 * MAT.density
    out = evaluate_contact(spec, 1.0, 0.0, 0.0, delta, R, R, R / 2, m / 2, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0,
                           0.0, 0.0, 0.0, 0.0, 0.0, 0.0, ht, 0, prm, 0, 1e-6)
    return out[0]


def test_every_registered_law_has_a_reference_a_version_and_composes():
    for family in FAMILIES:
        assert REGISTRY[family], family
        for name, law in REGISTRY[family].items():
            assert law.reference and law.version >= 1 and law.fn.__doc__, (family, name)
    m = ContactModel(normal="jkr", cohesion="capillary", cap="pulloff", rolling="sds")
    assert ContactModel.parse(m.spec) == m
    assert m.key == {"normal": "jkr@1", "cohesion": "capillary@1", "damping": "edem@1", "cap": "pulloff@1",
                     "tangential": "mindlin@1", "rolling": "sds@1"}
    with pytest.raises(CalibError, match="unknown rolling law 'epsd'"):
        ContactModel(rolling="epsd")


@pytest.mark.parametrize("it, want", [
    (Interaction(), ContactModel()),
    (Interaction(surface_energy=0.5), ContactModel(normal="jkr")),
    (Interaction(surface_energy=0.5, caps_pulloff=1.0, rolling_spring=1.0),
     ContactModel(normal="jkr", cap="pulloff", rolling="sds")),
    (Interaction(rolling_own_spin=1.0, friction_net_force=1.0), ContactModel(cap="net", rolling="standard")),
    (Interaction(surface_tension=0.07), ContactModel(cohesion="capillary")),
])
def test_interactions_name_their_laws(it, want):
    walls = Interaction(rolling_own_spin=it.rolling_own_spin, friction_net_force=it.friction_net_force,
                        rolling_spring=it.rolling_spring, caps_pulloff=it.caps_pulloff)
    assert contact_model(it, walls, walls) == want
    if it.rolling_spring:  # one law a run: the walls cannot have another
        with pytest.raises(CalibError, match="the walls take the grains' contact laws"):
            contact_model(it, Interaction(), Interaction())


def test_capillary_force_at_contact_is_two_pi_r_gamma_cos_theta():
    ht = np.zeros((1, HIST))
    assert _normal_force(0.0, ht) == pytest.approx(-F0, rel=1e-12)
    assert ht[0, BRIDGE] == 1.0
    # in contact the bridge adds F(0) to the elastic force
    delta = 2e-6
    dry = _normal_force(delta, np.zeros((1, HIST)), Interaction(0.0, 0.0, 1.0), ContactModel().spec)
    assert _normal_force(delta, np.zeros((1, HIST))) == pytest.approx(dry - F0, rel=1e-12)


def test_capillary_force_decays_as_willett_and_ruptures_as_lian():
    ht = np.zeros((1, HIST))
    _normal_force(0.0, ht)  # the bridge forms on contact
    gaps = np.linspace(0.0, S_RUPTURE * (1 - 1e-9), 60)
    f = np.array([_normal_force(-S, ht) for S in gaps])
    np.testing.assert_allclose(f, [willett(S) for S in gaps], rtol=1e-12)
    assert np.all(np.diff(f) > 0)  # the pull falls monotonically with the gap
    assert f[-1] == pytest.approx(willett(S_RUPTURE), rel=1e-9) and f[-1] < 0
    assert _normal_force(-S_RUPTURE * (1 + 1e-9), ht) == 0.0 and ht[0, BRIDGE] == 0.0  # ruptured
    # hysteresis: once ruptured, nothing pulls within the rupture distance until the grains touch
    assert _normal_force(-0.5 * S_RUPTURE, ht) == 0.0
    assert _normal_force(0.0, ht) == pytest.approx(-F0, rel=1e-12)


def test_a_separating_pair_loses_the_bridges_work_of_rupture():
    """Two touching grains flying apart (no gravity, no damping): their kinetic energy falls by
    W = int_0^S_c |F(S)| dS, the energy a bridge takes with it when it ruptures."""
    v = 0.2  # its kinetic energy ~15 W: the pair escapes
    p = Particles([[0, 0, 0], [2 * R, 0, 0]], [R, R], vel=[[-v, 0, 0], [v, 0, 0]])
    s = System(p, material=MAT, pp=WET, gravity=(0, 0, 0), walls=Walls(floor=False), safety=0.05)
    ke0 = s.kinetic_energy()
    s.advance(int(2 * S_RUPTURE / (2 * v) / s.dt))  # well past the rupture distance
    assert s.particles.pos[1, 0] - s.particles.pos[0, 0] > 2 * R + S_RUPTURE
    work = quad(lambda S: -willett(S), 0, S_RUPTURE)[0]
    assert ke0 - s.kinetic_energy() == pytest.approx(work, rel=1e-3)


def test_walls_hold_no_bridge_and_dry_grains_no_liquid():
    from calib_cli.dem.heap import interactions

    pp, floor, cyl = interactions({"surface_tension": 0.07})
    assert pp.surface_tension == 0.07 and floor.surface_tension == 0 and cyl.surface_tension == 0
    assert contact_model(*interactions({})).cohesion == "none"
    with pytest.raises(CalibError, match="surface_tension"):
        Interaction(surface_tension=-0.1).validate()
    with pytest.raises(CalibError, match="contact_angle"):
        Interaction(contact_angle=95.0).validate()


def test_a_law_declares_its_own_parameters_in_its_module_alone():
    """Adding a law is its module plus one registry entry: the interaction, the heap test's parameters,
    the walls' rule, validation and diagnose's candidates take its values from its declaration, so no
    other module of the package names them."""
    import pathlib

    import calib_cli
    from calib_cli.dem.heap import LAWS, PARAMETERS, PARTICLE_DEFAULTS, WALL_ZERO
    from calib_cli.dem.laws import REGISTRY
    from calib_cli.model import EFFECTS

    package = pathlib.Path(calib_cli.__file__).parent
    for law in (law for family in REGISTRY.values() for law in family.values() if law.params):
        home = pathlib.Path(__import__(law.fn.py_func.__module__, fromlist=["_"]).__file__)
        for p in law.params:
            assert p.name in PARAMETERS and PARTICLE_DEFAULTS[p.name] == p.default
            assert getattr(Interaction(), p.name) == p.default
            assert (p.name in LAWS) == p.setting and (p.name in WALL_ZERO) == p.wall_zero
            named = [f for f in package.rglob("*.py") if f != home and p.name in f.read_text()]
            assert not named, f"{p.name} of law {law.name} is named outside {home.name}: {named}"
        if law.effect is not None:
            assert EFFECTS[law.effect.name] is law.effect
            # its parameter is one of the law's calibrated values, and the effect's range lies within what the
            # law accepts (a calibration must not draw a value the heap's check refuses mid-campaign)
            own = next(p for p in law.params if p.name == law.effect.parameter)
            assert not own.setting and own.low <= law.effect.low < law.effect.high <= own.high
            # a model without the effect leaves its value out of the heap's parameters: adding a law keeps
            # every heap simulated before it under its cache key
            assert not law.effect.pinned_when_absent
    assert EFFECTS["capillary"].parameter == "surface_tension"


def test_two_laws_of_one_family_selected_are_refused_not_resolved_by_order(monkeypatch):
    """A second cohesion law selected by the same values as the capillary bridge: the run cannot have both."""
    from dataclasses import replace

    from calib_cli.dem.laws import compose

    twin = replace(REGISTRY["cohesion"]["capillary"], name="twin")
    monkeypatch.setitem(REGISTRY["cohesion"], "twin", twin)
    with pytest.raises(CalibError, match=r"select 2 cohesion laws \(capillary, twin\)"):
        compose(Interaction(surface_tension=0.07), Interaction(), Interaction())
    assert compose(Interaction(), Interaction(), Interaction()).cohesion == "none"


def test_a_bad_value_names_itself_in_one_short_line():
    with pytest.raises(CalibError) as e:
        Interaction(contact_angle=95.0).validate("particle-particle")
    assert str(e.value).startswith("particle-particle: contact_angle") and str(e.value).endswith("(got 95)")
    assert "Interaction(" not in str(e.value)
    with pytest.raises(CalibError, match=r"static_friction must be finite \(got nan\)"):
        Interaction(static_friction=float("nan")).validate()


def test_the_gpu_compile_check_composes_every_registered_law():
    """benchmarks/gpu_compile.py compiles the GPU kernels of a few compositions (on a machine with the [gpu]
    extra): together they must use every law, so a law added to the registry is compiled for the GPU too.
    Its list is read as text: importing the benchmark would leave numba's CUDA simulator."""
    import ast
    import pathlib

    src = (pathlib.Path(__file__).parents[1] / "benchmarks" / "gpu_compile.py").read_text()
    node = next(n for n in ast.parse(src).body if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", "") ==
                "COMPOSITIONS")
    used = set()
    for grains, walls in ast.literal_eval(node.value):
        w = Interaction(static_friction=0.3, **walls)
        m = contact_model(Interaction(static_friction=0.5, rolling_friction=0.2, **grains), w, w)
        used |= {(f, getattr(m, f)) for f in FAMILIES}
    missing = {(f, name) for f in FAMILIES for name in REGISTRY[f]} - used
    assert not missing, f"add a composition using {sorted(missing)} to benchmarks/gpu_compile.py's COMPOSITIONS"
