"""The kernel against analytic results (SPEC section 7, issue 3)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from calib_cli.dem.forces import evaluate_contact
from calib_cli.dem.laws import ContactModel
from calib_cli.dem.laws.columns import A_OLD, G_ROLL, HIST, K_ROLL
from calib_cli.dem.laws.normal import (jkr_cutoff_overlap, jkr_force_of_radius, jkr_overlap_of_radius, normal_law,
                                       normal_law_a)
from calib_cli.dem.materials import Interaction, Material, contact_model, effective_moduli
from calib_cli.dem.neighbours import build_pairs
from calib_cli.dem.timestep import hertz_contact_time, rayleigh_time_step
from calib_cli.dem.system import Particles, System, UnstableError, Walls
from calib_cli.errors import CalibError

R = 2e-3
G = 9.81
MAT = Material(5e6, 0.25, 2600.0)
ES, GS = effective_moduli(MAT, MAT)


def pair(e=0.5, mu=0.0, mur=0.0, gamma=0.0, v=0.5, offset=(0.0, 0.0), w=((0, 0, 0), (0, 0, 0)), safety=0.01,
         radii=(R, R), spring=0.0, precision="double"):
    p = Particles([[0, 0, 0.1], [radii[0] + radii[1] + 1e-6, offset[0], 0.1 + offset[1]]], list(radii),
                  vel=[[v, 0, 0], [-v, 0, 0]], omg=list(w))
    return System(p, material=MAT, pp=Interaction(mu, mur, e, gamma, 0.0, 0.0, spring), gravity=(0, 0, 0),
                  walls=Walls(floor=False), safety=safety, precision=precision)


def on_floor(mu=0.5, mur=0.0, e=0.5, grav=(0, 0, -G), safety=0.1, own_spin=0.0, spring=0.0, precision="double"):
    p = Particles([[0, 0, R * 0.9995]], [R])
    it = Interaction(mu, mur, e, 0.0, own_spin, 0.0, spring)
    s = System(p, material=MAT, wall_material=MAT, pp=it, floor=it, cylinder=it, gravity=grav, safety=safety,
               precision=precision)
    s.advance(int(0.02 / s.dt))  # come to rest on the floor
    return s


# ---------------------------------------------------------------- normal contact
# "mixed": velocities, forces and contact histories stored as float32 (calib_cli.dem.system.PRECISIONS)
@pytest.mark.parametrize("precision", ["double", "mixed"])
@pytest.mark.parametrize("e", [0.2, 0.3, 0.5, 0.7, 0.9])
def test_head_on_restitution(e, precision):
    s = pair(e=e, precision=precision)
    s.advance(int(2e-3 / s.dt))
    v = s.particles.vel
    assert v[1, 0] - v[0, 0] == pytest.approx(e * 1.0, abs=0.005)


def test_hertz_contact_time_and_elastic_energy():
    s = pair(e=1.0)
    ke0 = s.kinetic_energy()
    steps = 0
    for _ in range(int(2e-3 / s.dt)):
        s.advance(1)
        d = np.linalg.norm(s.particles.pos[0] - s.particles.pos[1])
        steps += d < 2 * R
    Rs, ms = R / 2, s.mass[0] / 2
    assert steps * s.dt == pytest.approx(hertz_contact_time(Rs, ES, ms, 1.0), rel=0.01)
    assert s.kinetic_energy() == pytest.approx(ke0, rel=1e-4)  # e = 1, mu = 0: energy conserved


def test_hertz_static_overlap_on_floor():
    s = on_floor(e=0.2)
    m = s.mass[0]
    delta = R - s.particles.pos[0, 2]
    Es_w, _ = effective_moduli(MAT, MAT)
    expected = (3 * m * G / (4 * Es_w * math.sqrt(R))) ** (2 / 3)
    assert delta == pytest.approx(expected, rel=1e-3)


def test_hertz_law_and_jkr_reduces_to_hertz():
    for d in [1e-7, 1e-6, 1e-5]:
        f, frep, a = normal_law(d, 1e-3, ES, 0.0)
        assert f == pytest.approx(4 / 3 * ES * math.sqrt(1e-3) * d**1.5, rel=1e-12)
        assert normal_law(d, 1e-3, ES, 1e-9)[0] == pytest.approx(f, rel=1e-3)
    assert normal_law(-1e-7, 1e-3, ES, 0.0) == (0.0, 0.0, 0.0)


# ---------------------------------------------------------------- JKR
@pytest.mark.parametrize("gamma,Rs", [(0.5, 1e-3), (1.25, 7.5e-4), (2.0, 2e-3)])
def test_jkr_curve_minimum_and_cutoff(gamma, Rs):
    # the law follows the paper's Eqs. 2-3 parametrically in a (stable branch)
    s = (math.pi * gamma / ES * Rs**2) ** (1 / 3)
    for u in np.linspace(0.7, 5.0, 30):
        a = u * s
        d = jkr_overlap_of_radius(a, Rs, ES, gamma)
        f, frep, a_k = normal_law(d, Rs, ES, gamma)
        assert a_k == pytest.approx(a, rel=1e-9)
        assert f == pytest.approx(jkr_force_of_radius(a, Rs, ES, gamma), rel=1e-9, abs=1e-12)
        assert frep == pytest.approx(4 * ES * a**3 / (3 * Rs), rel=1e-9)
    # the minimum of the force law is -3 pi g R* (not EDEM's quoted -3/2 pi g R*)
    dc = jkr_cutoff_overlap(Rs, ES, gamma)
    ds = np.linspace(dc * 0.999, -dc, 20001)
    fmin = min(normal_law(d, Rs, ES, gamma)[0] for d in ds)
    assert fmin == pytest.approx(-3 * math.pi * gamma * Rs, rel=1e-5)
    # the cutoff gap: d_c = a_c^2/R* - sqrt(4 pi g a_c / E*), a_c = [9 pi g R*^2/(2E*) (3/4 - 1/sqrt 2)]^(1/3)
    a_c = (9 * math.pi * gamma * Rs**2 / (2 * ES) * (0.75 - 1 / math.sqrt(2))) ** (1 / 3)
    assert dc == pytest.approx(a_c**2 / Rs - math.sqrt(4 * math.pi * gamma * a_c / ES), rel=1e-12)
    assert normal_law(dc * 1.0001, Rs, ES, gamma) == (0.0, 0.0, 0.0)  # beyond the cutoff: detached
    assert normal_law(dc * 0.9999, Rs, ES, gamma)[0] < 0  # just inside: still attracting
    # EDEM's -3/2 pi g R* is the force at a_c
    assert jkr_force_of_radius(a_c, Rs, ES, gamma) == pytest.approx(-1.5 * math.pi * gamma * Rs, rel=1e-4)
    # hysteresis: surfaces that were apart feel nothing until they touch
    assert normal_law(dc * 0.5, Rs, ES, gamma, engaged=False) == (0.0, 0.0, 0.0)
    assert normal_law(0.0, Rs, ES, gamma, engaged=False)[0] == pytest.approx(-8 / 9 * 3 * math.pi * gamma * Rs,
                                                                            rel=1e-6)


def jkr_work_of_separation(Rs, Es, gamma):
    """Work to pull a JKR contact from zero load (u^(3/2) = 3) to its cutoff: -integral of F d(delta)."""
    from scipy.integrate import quad

    k = math.pi * gamma / Es
    a0 = 3 ** (2 / 3) * (k * Rs**2) ** (1 / 3)
    a_c = (9 * math.pi * gamma * Rs**2 / (2 * Es) * (0.75 - 1 / math.sqrt(2))) ** (1 / 3)
    dd_da = lambda a: 2 * a / Rs - math.sqrt(k / a)  # noqa: E731 - d(delta)/da of delta = a^2/R* - 2 sqrt(k a)
    w, _ = quad(lambda a: -jkr_force_of_radius(a, Rs, Es, gamma) * dd_da(a), a_c, a0, epsabs=0, epsrel=1e-12)
    return w


def test_jkr_pull_off_force_is_stiffness_free_but_the_work_of_separation_is_not():
    """docs/physics.md 'Stiffness': a reduced modulus keeps the pull-off force 3 pi g R* but raises the
    work that breaks a contact as E*^(-2/3) (g^(5/3) R*^(4/3)): 100x softer grains stick 21.5x harder."""
    Rs, gamma = 1e-3, 1.0
    w = jkr_work_of_separation(Rs, ES, gamma)
    assert w > 0
    for fe, fg, fr in [(10.0, 1.0, 1.0), (0.01, 1.0, 1.0), (1.0, 2.0, 1.0), (1.0, 1.0, 3.0), (5.0, 0.3, 0.5)]:
        expect = fe ** (-2 / 3) * fg ** (5 / 3) * fr ** (4 / 3)
        assert jkr_work_of_separation(Rs * fr, ES * fe, gamma * fg) / w == pytest.approx(expect, rel=1e-8)
    for fe in (0.01, 1.0, 100.0):  # the pull-off force does not move
        dc = jkr_cutoff_overlap(Rs, ES * fe, gamma)
        fmin = min(normal_law(d, Rs, ES * fe, gamma)[0] for d in np.linspace(dc * 0.999, -dc, 4001))
        assert fmin == pytest.approx(-3 * math.pi * gamma * Rs, rel=1e-4)


@settings(max_examples=300, deadline=None)
@given(u=st.floats(0.69, 6.0), u_prev=st.floats(0.3, 8.0), gamma=st.floats(0.05, 3.0), Rs=st.floats(5e-4, 3e-3))
def test_jkr_warm_start_finds_the_stable_root(u, u_prev, gamma, Rs):
    # the kernel warm-starts each contact's solve from its radius at the last step, which may lie
    # anywhere (a contact near the cutoff, a fresh impact): the root is the same to 1e-12
    s = (math.pi * gamma / ES * Rs**2) ** (1 / 3)
    d = jkr_overlap_of_radius(u * s, Rs, ES, gamma)
    f, frep, a = normal_law_a(d, Rs, ES, gamma, u_prev * s)
    assert a == pytest.approx(u * s, rel=1e-12)
    assert f == pytest.approx(jkr_force_of_radius(u * s, Rs, ES, gamma), rel=1e-10, abs=1e-12 * gamma * Rs)


@pytest.mark.parametrize("precision", ["double", "mixed"])
def test_jkr_pair_settles_at_zero_load_overlap(precision):
    """In mixed precision the contact radius the JKR solver warm-starts from is float32: the root is not."""
    gamma = 1.0
    s = pair(e=0.3, gamma=gamma, v=0.001, safety=0.1, precision=precision)
    s.advance(int(0.05 / s.dt))
    d = 2 * R - np.linalg.norm(s.particles.pos[0] - s.particles.pos[1])
    # F = 0 where u^(3/2) = 3: delta0 = scale (u^2 - 2 sqrt u)
    u = 3 ** (2 / 3)
    scale = (math.pi * gamma / ES) ** (2 / 3) * (R / 2) ** (1 / 3)
    assert d == pytest.approx(scale * (u * u - 2 * math.sqrt(u)), rel=1e-3)


def test_jkr_pair_detaches_beyond_cutoff():
    """Pulled apart fast, a cohesive pair separates; the last attractive gap is the cutoff."""
    gamma = 1.0
    s = pair(e=0.9, gamma=gamma, v=-0.1, safety=0.005)  # pulled apart from a just-touching start
    s.ht[0, 3] = 1e-9  # engaged contact
    gaps = []
    for _ in range(3000):
        s.advance(1)
        gaps.append((2 * R - np.linalg.norm(s.particles.pos[0] - s.particles.pos[1]), s.ht[0, 3]))
    gaps = np.array(gaps)
    engaged = gaps[gaps[:, 1] > 0, 0]
    dc = jkr_cutoff_overlap(R / 2, ES, gamma)
    assert engaged.min() >= dc
    assert engaged.min() == pytest.approx(dc, rel=0.03)
    assert gaps[-1, 1] == 0.0  # detached


# ---------------------------------------------------------------- friction and rolling
def test_sliding_sphere_slips_until_five_sevenths():
    mu, v0 = 0.3, 0.5
    s = on_floor(mu=mu)
    s.particles.vel[0] = [v0, 0, 0]
    t0 = s.t
    t_stick = None
    for _ in range(int(0.1 / s.dt)):
        s.advance(1)
        slip = s.particles.vel[0, 0] - s.particles.omg[0, 1] * R
        if t_stick is None and slip < 1e-3 * v0:
            t_stick = s.t - t0
    assert s.particles.vel[0, 0] == pytest.approx(5 / 7 * v0, rel=2e-3)
    assert t_stick == pytest.approx(2 * v0 / (7 * mu * G), rel=0.01)


@pytest.mark.parametrize("wall", ["floor", "cylinder"])
def test_floor_and_cylinder_each_use_their_own_friction(wall):
    """Each wall's contacts take that wall's interaction: a sphere sliding on the floor, or down the
    cylinder's inside with gravity pressing it outwards, slips until v = 5/7 v0 at t = 2 v0 / (7 mu g)
    with that wall's mu, the other wall's being different (the heap's floor_* and cylinder_*)."""
    v0, mu = 0.5, {"floor": 0.2, "cylinder": 0.6}
    Rc = 0.1  # the floor's sphere slides ~30 mm before it rolls
    at_floor = wall == "floor"
    p = Particles([[0, 0, R * 0.9995] if at_floor else [Rc - R * 0.9995, 0, 0.1]], [R])
    s = System(p, material=MAT, wall_material=MAT, pp=Interaction(0.5, 0.0, 0.5),
               floor=Interaction(mu["floor"], 0.0, 0.5), cylinder=Interaction(mu["cylinder"], 0.0, 0.5),
               gravity=(0, 0, -G) if at_floor else (G, 0, 0), walls=Walls(floor=at_floor, cylinder_radius=Rc),
               safety=0.1)
    s.advance(int(0.02 / s.dt))
    ax = 0 if at_floor else 2
    s.particles.vel[0] = 0.0
    s.particles.vel[0, ax] = v0
    t0, t_stick = s.t, None
    for _ in range(int(0.2 / s.dt)):
        s.advance(1)
        if t_stick is None and s.particles.vel[0, ax] - s.particles.omg[0, 1] * R < 1e-3 * v0:
            t_stick = s.t - t0
            break
    assert t_stick == pytest.approx(2 * v0 / (7 * mu[wall] * G), rel=0.01)
    assert s.particles.vel[0, ax] == pytest.approx(5 / 7 * v0, rel=3e-3)


@pytest.mark.parametrize("own_spin,spring", [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)])
def test_rolling_friction_decelerates_at_five_sevenths_mu_r_g(own_spin, spring):
    """Against the floor (no spin) EDEM's 'Standard' law (own_spin 1) is the relative law; the
    rolling spring, slipping at its cap, gives the same torque."""
    mur = 0.05
    s = on_floor(mu=0.5, mur=mur, own_spin=own_spin, spring=spring)
    s.particles.vel[0] = [0.3, 0, 0]
    s.particles.omg[0] = [0, 0.3 / R, 0]
    ts, vs = [], []
    for _ in range(int(0.05 / s.dt)):
        s.advance(1)
        ts.append(s.t)
        vs.append(s.particles.vel[0, 0])
    a = np.polyfit(ts[50:], vs[50:], 1)[0]
    assert a == pytest.approx(-5 / 7 * mur * G, rel=0.01)


@pytest.mark.parametrize("precision", ["double", "mixed"])
@pytest.mark.parametrize("spring", [0.0, 1.0])
@pytest.mark.parametrize("mur,tan_theta,holds", [(0.3, 0.25, True), (0.3, 0.35, False), (0.0, 0.2, False)])
def test_sphere_on_incline(mur, tan_theta, holds, spring, precision):
    th = math.atan(tan_theta)
    grav = (G * math.sin(th), 0.0, -G * math.cos(th))  # floor tilted by theta
    s = on_floor(mu=0.9, mur=mur, grav=(0, 0, -G), spring=spring, precision=precision)
    s.grav[:] = grav
    s.particles.vel[0] = 0
    ts, vs = [], []
    for _ in range(int(0.05 / s.dt)):
        s.advance(1)
        ts.append(s.t)
        vs.append(s.particles.vel[0, 0])
    v = vs[-1]
    if holds:
        assert abs(v) < 1e-3
    else:
        a = 5 / 7 * G * (math.sin(th) - mur * math.cos(th))
        half = len(ts) // 2  # after the start, where the rolling limit engages while w ~ 0
        assert np.polyfit(ts[half:], vs[half:], 1)[0] == pytest.approx(a, rel=0.01)
        # below the slip limit: rolling without sliding
        assert s.particles.omg[0, 1] * R == pytest.approx(v, rel=0.02)


def test_rolling_spring_holds_a_static_torque_where_the_constant_torque_creeps():
    """Below its cap (tan theta < mu_r) the spring-dashpot-slider holds the sphere still, its two
    springs carrying exactly the static load f = m g sin(theta): f / (8 G* a) tangentially and
    f (R - delta) / (R k_r) in rolling (torque balance about the centre). The constant directional torque gives no torque at rest, so gravity turns
    the sphere a little every step and it creeps at a speed of order g dt (docs/physics.md)."""
    from calib_cli.dem.laws.rolling import rolling_spring_constants

    th = math.atan(0.25)
    end = {}
    for spring in (0.0, 1.0):
        s = on_floor(mu=0.9, mur=0.3, spring=spring)
        s.grav[:] = (G * math.sin(th), 0.0, -G * math.cos(th))
        s.advance(int(0.1 / s.dt))
        end[spring] = s
    held, crept = end[1.0], end[0.0]
    assert abs(held.particles.vel[0, 0]) < 1e-12 and abs(held.particles.omg[0, 1]) < 1e-9
    assert crept.particles.vel[0, 0] > 1e-5  # ~ g dt: the constant torque cannot hold it
    f = held.mass[0] * G * math.sin(th)
    h = held.hf[0]
    assert h[0] == pytest.approx(f / (8 * GS * h[3]), rel=1e-6)  # tangential spring, F_t = -8 G* a h
    kr, _ = rolling_spring_constants(GS, held.mass[0])
    delta = R - held.particles.pos[0, 2]  # F_t acts at R - delta, the rolling force at R* = R
    assert np.hypot(h[5], h[6]) == pytest.approx(f * (R - delta) / R / kr, rel=1e-6)


def _spring_torques(wi, wj, dt=1e-7, mur=0.2, delta=2e-5, gr=0.0):
    """Torques of one Hertz pair contact under the rolling spring (no sliding friction), n = +x."""
    ti, tj, fel, _, ht, prm = _pair_contact(Interaction(0.0, mur, 0.5, 0.0, 0.0, 0.0, 1.0), wi, wj, delta, dt, gr)
    return ti, tj, prm[0, K_ROLL], fel, ht[0]


def test_rolling_spring_contact_law():
    """One step of the spring-dashpot-slider (LAMMPS `rolling sds`): u = v_r dt with v_r = R* (w_i -
    w_j) x n; F_r = -k_r u - g_r v_r; torque R* n x F_r on i and its opposite on j (angular
    momentum conserved, unlike the constant torque between unequal grains); capped at mu_r |F_n|
    x 2 R* (= mu_r F_n R for equal grains, the constant torque's size); spin about the normal
    (twist) not resisted."""
    Rs, w, dt, gr = R / 2, 10.0, 1e-7, 1e-4
    ti, tj, kr, fel, h = _spring_torques((0, 0, w), (0, 0, 0), dt=dt, gr=gr)
    vr = Rs * w  # (0, 0, w) x (1, 0, 0) = (0, w, 0)
    assert h[6] == pytest.approx(vr * dt, rel=1e-12)
    assert ti == pytest.approx([0, 0, -Rs * (kr * vr * dt + gr * vr)], rel=1e-9)  # opposes w_i
    assert np.allclose(ti + tj, 0, atol=0)
    ti, tj, kr, fel, h = _spring_torques((0, 0, 1e6), (0, 0, 0))  # far past the cap: slides at it
    assert ti == pytest.approx([0, 0, -0.2 * fel * 2 * Rs], rel=1e-9)
    assert h[6] * kr == pytest.approx(0.2 * fel * 2, rel=1e-9)  # the spring rescaled to carry the cap
    ti, tj, _, _, h = _spring_torques((w, 0, 0), (0, 0, 0))  # twist: no rolling displacement
    assert np.allclose(ti, 0, atol=0) and np.allclose(h[5:8], 0, atol=0)


def test_rolling_spring_excludes_the_own_spin_law():
    with pytest.raises(CalibError, match="exclude each other"):
        Interaction(0.5, 0.1, 0.5, 0.0, 1.0, 0.0, 1.0).validate()
    with pytest.raises(CalibError, match="rolling_spring must be 0 or 1"):
        Interaction(0.5, 0.1, 0.5, 0.0, 0.0, 0.0, 0.5).validate()


# ---------------------------------------------------------------- conservation
@settings(max_examples=20, deadline=None)
@given(v=st.floats(0.05, 0.5), off=st.floats(-1.5e-3, 1.5e-3), offz=st.floats(-1.5e-3, 1.5e-3),
       w=st.lists(st.floats(-200, 200), min_size=6, max_size=6), mu=st.floats(0.0, 1.0),
       r2=st.floats(1.2e-3, 3e-3), gamma=st.sampled_from([0.0, 1.0]), mur=st.sampled_from([0.0, 0.05, 0.4]))
def test_collision_conserves_momentum_and_angular_momentum(v, off, offz, w, mu, r2, gamma, mur):
    """With rolling friction only the spring law conserves angular momentum between unequal grains
    (its torques are opposite; the constant torques are mu_r F_n R_i and R_j)."""
    s = pair(e=0.5, mu=mu, mur=mur, gamma=gamma, v=v, offset=(off, offz), w=(w[:3], w[3:]), safety=0.05,
             radii=(R, r2), spring=1.0 if mur else 0.0)
    p = s.particles

    def P():
        return (s.mass[:, None] * p.vel).sum(0)

    def L():
        return (s.mass[:, None] * np.cross(p.pos, p.vel)).sum(0) + (p.omg / s.inv_inertia[:, None]).sum(0)

    P0, L0 = P(), L()
    s.advance(int(1.5e-3 / s.dt))
    assert np.allclose(P(), P0, rtol=0, atol=1e-12 * (1 + np.abs(P0).max()))
    scale = np.abs(s.mass[0] * np.linalg.norm(p.pos[0]) * v) + 1e-20
    assert np.allclose(L(), L0, rtol=0, atol=1e-9 * scale)


def test_undamped_elastic_system_energy_does_not_grow():
    rng = np.random.default_rng(3)
    n = 60
    pos = np.column_stack([rng.uniform(-8e-3, 8e-3, n), rng.uniform(-8e-3, 8e-3, n), rng.uniform(3e-3, 4e-2, n)])
    keep = [0]
    for i in range(1, n):  # non-overlapping start
        if all(np.linalg.norm(pos[i] - pos[j]) > 4.2e-3 for j in keep):
            keep.append(i)
    pos = pos[keep]
    p = Particles(pos, np.full(len(pos), R), vel=rng.normal(0, 0.2, (len(pos), 3)))
    it = Interaction(0.0, 0.0, 1.0, 0.0)
    s = System(p, material=MAT, wall_material=MAT, pp=it, floor=it, cylinder=it,
               walls=Walls(True, 1.2e-2, 0.0, np.inf), safety=0.05)
    e0 = s.kinetic_energy() + s.potential_energy()
    for _ in range(10):
        s.advance(int(0.01 / s.dt))
        e = s.kinetic_energy() + s.potential_energy()
        assert e <= e0 * (1 + 2e-3) + 1e-12
    assert e == pytest.approx(e0, rel=5e-3)


# ---------------------------------------------------------------- numerics
def test_rayleigh_step_and_refusal_of_unstable_step():
    t = rayleigh_time_step(1.5e-3, 2600, 5e6, 0.25)
    assert t == pytest.approx(math.pi * 1.5e-3 * math.sqrt(2600 / 5e6) / (0.1631 * 0.25 + 0.8766))
    p = Particles([[0, 0, R]], [R])
    with pytest.raises(CalibError, match="critical step"):
        System(p, material=MAT, dt=2 * t)
    s = System(Particles([[0, 0, 1.5e-3]], [1.5e-3]), material=MAT, pp=Interaction(surface_energy=2.0),
               floor=Interaction(surface_energy=2.0))
    assert s.jkr_dt < s.rayleigh_dt and s.dt == pytest.approx(0.2 * s.jkr_dt)  # cohesion limits the step
    s0 = System(Particles([[0, 0, 1.5e-3]], [1.5e-3]), material=MAT)
    assert s0.jkr_dt == math.inf and s0.dt == pytest.approx(0.2 * s0.rayleigh_dt)


def test_blow_up_is_an_error_not_an_angle():
    p = Particles([[0, 0, 0.1], [2 * R + 1e-6, 0, 0.1]], [R, R], vel=[[30, 0, 0], [-30, 0, 0]])
    s = System(p, material=MAT, gravity=(0, 0, 0), walls=Walls(floor=False))
    with pytest.raises(UnstableError, match="unstable"):
        s.advance(1000)


@settings(max_examples=15, deadline=None)
@given(n=st.integers(2, 120), seed=st.integers(0, 10_000), reach=st.floats(0, 2e-3))
def test_neighbour_list_matches_brute_force(n, seed, reach):
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-0.02, 0.02, (n, 3))
    pos[0] = [5.0, 0, 0]  # one escaped particle only coarsens the grid
    rad = rng.uniform(1e-3, 3e-3, n)
    pi, pj = np.zeros(n * n, np.int64), np.zeros(n * n, np.int64)
    cnt = build_pairs(pos, rad, reach, pi, pj)
    got = set(zip(pi[:cnt].tolist(), pj[:cnt].tolist()))
    want = {(i, j) for i in range(n) for j in range(i + 1, n)
            if np.linalg.norm(pos[i] - pos[j]) < rad[i] + rad[j] + reach}
    assert got == want
    keys = pi[:cnt] * n + pj[:cnt]
    assert np.all(np.diff(keys) > 0)  # sorted, for the history merge


def test_contact_history_survives_neighbour_list_rebuilds():
    """The same frictional run with a list rebuilt every step and rarely gives the same result."""
    def run(skin):
        p = Particles([[0, 0, R * 0.999], [2 * R * 0.999, 0, R * 0.999], [R * 0.999, 0, R * 2.74]], [R, R, R])
        it = Interaction(0.5, 0.1, 0.3, 0.0)
        s = System(p, material=MAT, wall_material=MAT, pp=it, floor=it, cylinder=it, skin_ratio=skin, safety=0.1)
        s.advance(int(0.03 / s.dt))
        return s
    a, b = run(1e-6), run(0.5)
    assert a.n_rebuilds > 50 * max(b.n_rebuilds, 1)
    np.testing.assert_allclose(a.particles.pos, b.particles.pos, rtol=0, atol=1e-9)


# ---------------------------------------------------------------- EDEM's 'Standard' rolling friction
def _pair_contact(it, wi, wj, delta=2e-5, dt=1e-10, g_roll=None):
    """One step of a Hertz pair contact between equal grains with spins wi, wj, n = +x:
    (torque on i, torque on j, elastic normal force, lever arm, history, parameter rows)."""
    from calib_cli.dem.materials import param_row

    prm = np.vstack([param_row(MAT, MAT, it)] * 3)
    if g_roll is not None:
        prm[:, G_ROLL] = g_roll
    ht = np.zeros((1, HIST))
    m = 4 / 3 * math.pi * R**3 * MAT.density
    inv_i = 1 / (0.4 * m * R * R)
    arm = R - delta / 2
    out = evaluate_contact(contact_model(it).spec, 1.0, 0.0, 0.0, delta, arm, arm, R / 2, m / 2, inv_i, inv_i, 1.0, 1.0, 0.0, 0.0, 0.0,
                          *wi, *wj, ht, 0, prm, 0, dt)
    fel = 4 / 3 * ES * math.sqrt(R / 2) * delta**1.5
    return np.array(out[3:6]), np.array(out[6:9]), fel, arm, ht, prm


def _rolling_torques(own: float, wi, wj, delta=2e-5, mur=0.2):
    """Torques of one Hertz pair contact (no sliding friction: rolling torques only), n = +x."""
    ti, tj, fel, arm, _, _ = _pair_contact(Interaction(0.0, mur, 0.5, 0.0, own), wi, wj, delta)
    return ti, tj, mur * fel * arm


def test_standard_rolling_brakes_each_body_against_its_own_spin():
    """EDEM 'Standard': tau_i = -mu_r F_n R_i w_i/|w_i|; the relative law (SPEC 5) sees no rolling
    between two grains spinning alike, the Standard law brakes both."""
    spin = (0.0, 0.0, 10.0)
    ti, tj, t = _rolling_torques(0.0, spin, spin)
    assert np.allclose(ti, 0) and np.allclose(tj, 0)
    ti, tj, t = _rolling_torques(1.0, spin, spin)
    assert ti == pytest.approx([0, 0, -t], rel=1e-9) and tj == pytest.approx([0, 0, -t], rel=1e-9)
    # counter-rotating grains (a grain rolling over another): the two laws agree
    for own in (0.0, 1.0):
        ti, tj, t = _rolling_torques(own, (0, 0, 10.0), (0, 0, -10.0))
        assert ti == pytest.approx([0, 0, -t], rel=1e-9) and tj == pytest.approx([0, 0, t], rel=1e-9)


@pytest.mark.parametrize("net", [0.0, 1.0])
def test_friction_cap_repulsive_part_or_net_force(net):
    """A sliding JKR contact carries mu_s x the repulsive part of the normal force (SPEC 5) or,
    with friction_net_force = 1, mu_s x |net normal force|."""
    from calib_cli.dem.materials import param_row

    gamma, mu, delta = 1.0, 0.3, 1e-6
    it = Interaction(mu, 0.0, 0.5, gamma, 0.0, net)
    assert contact_model(it) == ContactModel(normal="jkr", cap="net" if net else "repulsive")
    prm = np.vstack([param_row(MAT, MAT, it)] * 3)
    ht = np.zeros((1, HIST))
    ht[0, A_OLD] = -1.0  # an engaged contact, no warm start
    m = 4 / 3 * math.pi * R**3 * MAT.density
    inv_i = 1 / (0.4 * m * R * R)
    out = evaluate_contact(contact_model(it).spec, 1.0, 0.0, 0.0, delta, R, R, R / 2, m / 2, inv_i, inv_i, 1.0, 1.0, 0.0, 1.0, 0.0,
                          0.0, 0.0, 0.0, 0.0, 0.0, 0.0, ht, 0, prm, 0, 1e-6)  # sliding at 1 m/s along y
    fel, frep, _ = normal_law(delta, R / 2, ES, gamma)
    assert frep > 2 * abs(fel)  # near zero load the two caps differ by far
    assert abs(out[1]) == pytest.approx(mu * (abs(fel) if net else frep), rel=1e-9)


def _cohesive_pair_step(it, wi, delta):
    """One step of a JKR pair contact between equal grains sliding at 1 m/s along y with spin wi
    on i, n = +x: (force on i, torque on i, net elastic force, pull-off force 3 pi g R*)."""
    from calib_cli.dem.materials import param_row

    prm = np.vstack([param_row(MAT, MAT, it, 1e-4)] * 3)
    ht = np.zeros((1, HIST))
    ht[0, A_OLD] = -1.0  # an engaged contact, no warm start
    m = 4 / 3 * math.pi * R**3 * MAT.density
    inv_i = 1 / (0.4 * m * R * R)
    out = evaluate_contact(contact_model(it).spec, 1.0, 0.0, 0.0, delta, R, R, R / 2, m / 2, inv_i, inv_i, 1.0, 1.0, 0.0, 1.0, 0.0,
                          *wi, 0.0, 0.0, 0.0, ht, 0, prm, 0, 1e-3)
    fel, _, _ = normal_law(delta, R / 2, ES, it.surface_energy)
    return np.array(out[:3]), np.array(out[3:6]), fel, 3 * math.pi * it.surface_energy * R / 2


#: the overlap of a JKR pair of the tests' grains (R* = R/2, g = 1 J/m2) at zero net load:
#: a0^3 = 9 pi g R*^2 / E*, delta = a0^2 / R* - 2 sqrt(pi g a0 / E*)
_A0 = (9 * math.pi * 1.0 * (R / 2) ** 2 / ES) ** (1 / 3)
ZERO_LOAD = _A0**2 / (R / 2) - 2 * math.sqrt(math.pi * 1.0 * _A0 / ES)


@pytest.mark.parametrize("spring", [0.0, 1.0])
@pytest.mark.parametrize("delta", [ZERO_LOAD, 1e-6, -1e-7, 3e-5])
def test_pulloff_caps_are_thornton_and_lammps(spring, delta):
    """With caps_pulloff = 1 a sliding and rolling JKR contact carries mu_s |F_el + 2 F_c| and a
    rolling torque capped at mu_r |F_el + 2 F_c| R (F_c = 3 pi g R*: Thornton 1991, LAMMPS's
    jkr Fncrit), at any load: near zero load, in tension beyond contact, and under compression. The
    step is long (1 ms), so both the spring's and the constant torque's torque reach their cap."""
    mu, mur, gamma = 0.3, 0.2, 1.0
    base = dict(static_friction=mu, rolling_friction=mur, restitution=0.5, surface_energy=gamma,
                rolling_spring=spring)
    f0, t0, fel, fc = _cohesive_pair_step(Interaction(**base), (0.0, 0.0, 1e4), delta)
    f1, t1, _, _ = _cohesive_pair_step(Interaction(**base, caps_pulloff=1.0), (0.0, 0.0, 1e4), delta)
    crit = abs(fel + 2 * fc)
    assert abs(f1[1]) == pytest.approx(mu * crit, rel=1e-9)
    # the rolling torque: R* |F_r| <= R* mu_r crit x 2 for a pair (spring), mu_r crit R_i (constant)
    roll = t1[2] - (-R * f1[1])  # minus the sliding force's torque about i's centre: arm R, n = +x
    assert abs(roll) == pytest.approx(mur * crit * R, rel=1e-9)
    assert abs(t0[2] - (-R * f0[1])) == pytest.approx(mur * abs(fel) * R, rel=1e-9)
    if delta == ZERO_LOAD:  # the net force's caps vanish, the pull-off caps keep 2 F_c
        assert abs(fel) < 1e-6 * fc and abs(f1[1]) == pytest.approx(mu * 2 * fc, rel=1e-6)


def test_pulloff_caps_change_nothing_without_cohesion():
    """F_c = 0 without surface energy: caps_pulloff = 1 gives the same bits as 0 (Hertz)."""
    base = dict(static_friction=0.3, rolling_friction=0.2, restitution=0.5)
    for spring in (0.0, 1.0):
        a = _cohesive_pair_step(Interaction(**base, rolling_spring=spring), (0.0, 0.0, 1e4), 2e-5)
        b = _cohesive_pair_step(Interaction(**base, rolling_spring=spring, caps_pulloff=1.0), (0.0, 0.0, 1e4), 2e-5)
        assert all(np.array_equal(x, y) for x, y in zip(a, b))


def test_pulloff_caps_exclude_the_net_force_cap():
    with pytest.raises(CalibError, match="exclude"):
        Interaction(caps_pulloff=1.0, friction_net_force=1.0).validate()
    with pytest.raises(CalibError, match="caps_pulloff must be 0 or 1"):
        Interaction(caps_pulloff=0.5).validate()
