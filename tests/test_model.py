"""The forward model against the paper's equations and against itself."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chekan.physics import sensor as fm
from chekan.physics.units import arcmin_to_rad

G = 981922.05
K = 60428.0


def params(eps=(0.0, 0.0), gamma=0.0, m_level=(1024.0, 1024.0), b=(6.98, 6.88)):
    return fm.make_params(
        g_mgal=G,
        K_pix_per_rad=K,
        b_mgal_per_pix=b,
        m_level_pix=m_level,
        eps_rad=eps,
        gamma_rad=gamma,
    )


def test_small_angle_limit_eqs_7_to_10():
    """Level pendulum horizontal (m_h = m₀), no misalignment: Δg = bx + ax² with b = λ/K,
    a = g/2K² (eqs. 8–10), Δg = −g(1 − cos θ) (eq. 14); error O(x³)."""
    p = params()
    th = np.deg2rad(np.array([0.5, 1.0, 2.0]))
    m = np.asarray(fm.equilibrium_readings(p, 0.0, th))
    x = m - 1024.0
    _, lam, _ = fm.level_state(p)
    b = np.asarray(lam) / K
    np.testing.assert_allclose(b, [6.98, 6.88], rtol=1e-12)  # φ_h = 0: λ = bK exactly
    a = G / (2 * K**2)
    dg = -G * 2 * np.sin(th / 2) ** 2
    lhs = b * x + a * x**2
    # the remainder is the cubic term of eq. (6): G''' φ³/6 ≈ λ φ³/2 ⇒ ~λ/2 (x/K)³
    bound = 1.5 * np.asarray(lam) * (np.abs(x) / K) ** 3 / 2 + 1e-9
    assert np.all(np.abs(lhs - dg[:, None]) < bound)
    assert np.asarray(fm.quadratic_coefficient(p, 1024.0)) == pytest.approx(a, rel=1e-12)


def test_eq_11_to_14_misalignment_terms():
    """Small ε, γ: b x + a x² − dθx − eθ = Δg (eq. 11) with, in our conventions,
    d = gγ/K, e = g(ε + γ m_h/K) (m_h from the centre; eqs. 12–13 with γ_p = 90° − γ) and
    Δg = −g(1 − cos θ) the nominal increment (eq. 14); θ enters as sin θ."""
    eps, gam = arcmin_to_rad(2.0), arcmin_to_rad(3.0)
    mh = 1100.0
    p = params(eps=(eps, eps), gamma=gam, m_level=(mh, mh))
    th = np.deg2rad(np.array([-3.0, -1.0, 1.0, 3.0]))
    m = np.asarray(fm.equilibrium_readings(p, 0.0, th))[:, 0]
    x = m - mh
    a = np.asarray(fm.quadratic_coefficient(p, mh))[0]
    phi_h = (mh - 1024.0) / K
    s = np.sin(th)
    d, e = G * gam / K, G * (eps + gam * phi_h)
    nominal = -G * 2 * np.sin(th / 2) ** 2
    naive = 6.98 * x + a * x**2
    eq11 = naive - d * s * x - e * s
    assert np.max(np.abs(naive - nominal)) > 10.0  # the misalignment terms are tens of mGal
    np.testing.assert_allclose(eq11, nominal, atol=0.02)  # O(ε², γ², x³) remainder


def test_pm_tilts_cancel_eps_to_first_order_eq_17():
    th = np.deg2rad(4.0)
    base = params()
    mean0 = (
        np.asarray(fm.equilibrium_readings(base, 0.0, th) + fm.equilibrium_readings(base, 0.0, -th))
        / 2
    )
    diffs = []
    for e_arcmin in (5.0, 2.5):
        e = arcmin_to_rad(e_arcmin)
        p = params(eps=(e, -e))
        mp = np.asarray(fm.equilibrium_readings(p, 0.0, th))
        mm = np.asarray(fm.equilibrium_readings(p, 0.0, -th))
        diffs.append(np.abs((mp + mm) / 2 - mean0))
        # the asymmetry itself is first order and eq. (17) returns ε for each system
        eps17 = -(mp - mm) / (mp + mm - 2 * 1024.0) * th / 2
        np.testing.assert_allclose(eps17, [e, -e], rtol=2e-2)
    # second order: halving ε quarters the effect on the pair mean
    np.testing.assert_allclose(diffs[0] / diffs[1], 4.0, rtol=0.02)


def _params_of(vec):
    """Sensor parameters from (K, b₁, b₂, ε₁, ε₂, γ): what the derivative tests vary."""
    return fm.make_params(
        g_mgal=G,
        K_pix_per_rad=vec[0],
        b_mgal_per_pix=vec[1:3],
        m_level_pix=[1031.2, 1012.9],
        eps_rad=vec[3:5],
        gamma_rad=vec[5],
    )


def test_gradients_match_finite_differences():
    def f(vec):
        p = _params_of(vec)
        return fm.equilibrium_readings(p, 1e-4, jnp.deg2rad(jnp.array([2.0, -4.5]))).sum()

    f = jax.jit(f)
    x0 = jnp.array([K, 6.98, 6.88, 1e-3, -8e-4, 2e-3])
    g_ad = np.asarray(jax.grad(f)(x0))
    h = np.array([1.0, 1e-5, 1e-5, 1e-7, 1e-7, 1e-7])
    g_fd = np.array(
        [(f(x0.at[i].add(h[i])) - f(x0.at[i].add(-h[i]))) / (2 * h[i]) for i in range(6)]
    )
    np.testing.assert_allclose(g_ad, g_fd, rtol=1e-5, atol=1e-6)


def test_scale_factor_definitions_agree():
    p = params(m_level=(1031.2, 1012.9))
    # b at the level reading is the parameter itself
    np.testing.assert_allclose(fm.scale_factor(p, p.m_level_pix), [6.98, 6.88], rtol=1e-12)
    # eq. (24) is the linear approximation of the exact b(m₀)
    np.testing.assert_allclose(fm.scale_factor_at_centre(p), fm.scale_factor(p, 1024.0), rtol=1e-6)
    # the characteristic reproduces the tilt: G(m) − G(m_h) = −g(1 − cos θ) (no misalignment)
    th = np.deg2rad(5.0)
    m = fm.equilibrium_readings(p, 0.0, th)
    np.testing.assert_allclose(fm.characteristic(p, m), -G * (1 - np.cos(th)), rtol=1e-10)


def test_lag_filter_is_the_exponential():
    t = np.arange(0, 200.0)
    x = np.where(t < 50, 0.0, 10.0)
    tau = 17.0
    y = np.asarray(fm.lag_filter(jnp.asarray(x), np.ones_like(t), tau))
    k = t >= 50
    np.testing.assert_allclose(y[k], 10.0 * (1 - np.exp(-(t[k] - 49.0) / tau)), rtol=1e-12)
    np.testing.assert_allclose(fm.lag_filter_np(x, np.ones_like(t), tau), y, rtol=1e-12)
    dt = np.ones_like(t)
    dt[120] = 5.0  # a gap: the loop path
    y2 = fm.lag_filter_np(x, dt, tau)
    np.testing.assert_allclose(y2, np.asarray(fm.lag_filter(jnp.asarray(x), dt, tau)), rtol=1e-12)


@pytest.mark.parametrize("n", [1, 255, 256, 257, 1000])
def test_lag_uniform_is_the_exponential_across_its_blocks(n):
    """A step from a settled start at y₋₁ = 3 to x = 10: yₖ = 10 − 7ρ^{k+1}, exactly; two
    columns at once, and lengths around the block of 256 samples."""
    rho = float(np.exp(-1.0 / 17.0))
    x = np.full((n, 2), 10.0)
    y = fm.lag_uniform(x, rho, np.array([3.0, 3.0]))
    k = np.arange(n)
    np.testing.assert_allclose(y, (10.0 - 7.0 * rho ** (k + 1.0))[:, None] * [1, 1], rtol=1e-13)
    assert fm.lag_uniform(np.zeros((0, 2)), rho).shape == (0, 2)


def test_lag_uniform_equals_scipys_lfilter():
    from scipy.signal import lfilter

    x = np.random.default_rng(3).normal(1000.0, 50.0, size=(1500, 2))
    for rho in (float(np.exp(-1.0 / 30.0)), 0.5, 0.9999):
        want = lfilter([1.0 - rho], [1.0, -rho], x, axis=0)
        np.testing.assert_allclose(fm.lag_uniform(x, rho), want, rtol=1e-13)


def test_drift_polynomial():
    c = jnp.array([[0.1, 0.01], [-0.2, 0.0]])
    d = np.asarray(fm.drift_pix(c, np.array([0.0, 3600.0, 7200.0])))
    np.testing.assert_allclose(d[:, 0], [0.0, 0.11, 0.24])
    np.testing.assert_allclose(d[:, 1], [0.0, -0.2, -0.4])


def _unrolled_readings(vec, tx, ty):
    """Reference: the equilibrium by Newton differentiated through every step (no implicit
    rule), unrolled until its derivatives of every order have converged too."""
    p = _params_of(vec)
    phi_h, lam, _ = fm.level_state(p)
    du_z, u_y, u_zh = fm.up_vector_deviation(tx, ty, p.gamma_rad, p.eps_rad)
    args = (du_z, u_y, u_zh, phi_h, lam, p.g_mgal)
    delta = p.g_mgal * du_z / lam
    for _ in range(12):
        delta = delta - fm._residual(delta, *args) / fm._residual_derivative(delta, *args)
    return p.m_level_pix + p.K_pix_per_rad * delta


@pytest.mark.parametrize("ty_deg", [-5.1, 1.9, 4.4])
def test_second_derivatives_of_the_equilibrium_are_exact(ty_deg):
    """∂²m/∂θ∂p (the angle sensitivity's derivative, which the MAP Jacobian holds) and the
    Hessian in the parameters equal those of Newton differentiated through every step.
    One differentiable step from the stopped root (0.3.7) missed −F_δδ F_θ F_p/F_δ³:
    ≈ 3·10⁻⁴ of ∂²m/∂θ∂K."""
    tx = jnp.asarray(2e-4)
    ty = jnp.deg2rad(ty_deg)
    x0 = jnp.array([K, 6.98, 6.88, 1e-3, -8e-4, 2e-3])

    def model_readings(vec, t):
        return fm.equilibrium_readings(_params_of(vec), tx, t)

    def unrolled(vec, t):
        return _unrolled_readings(vec, tx, t)

    def sensitivity(f):
        return lambda vec: jax.jvp(lambda t: f(vec, t), (ty,), (jnp.ones(()),))[1]

    ours = jax.jacfwd(sensitivity(model_readings))(x0)  # (2 systems, 6 parameters)
    ref = jax.jacfwd(sensitivity(unrolled))(x0)
    scale = np.abs(np.asarray(ref)).max(axis=0)  # per parameter
    np.testing.assert_allclose(np.asarray(ours) / scale, np.asarray(ref) / scale, atol=1e-9)
    h_ours = jax.hessian(lambda v: model_readings(v, ty).sum())(x0)
    h_ref = jax.hessian(lambda v: unrolled(v, ty).sum())(x0)
    hs = np.abs(np.asarray(h_ref)).max()
    np.testing.assert_allclose(np.asarray(h_ours) / hs, np.asarray(h_ref) / hs, atol=1e-9)


def test_host_equilibrium_is_the_compiled_one():
    """The numpy evaluation (settled items, figures) equals the jitted forward model to
    rounding, about either axis and both, with misalignments, for scalars and arrays."""
    rng = np.random.default_rng(7)
    p = params(eps=(3e-3, -2e-3), gamma=4e-3, m_level=(900.0, 1150.0))
    tx = rng.uniform(-0.095, 0.095, 500) * (rng.uniform(size=500) < 0.6)
    ty = rng.uniform(-0.095, 0.095, 500) * (rng.uniform(size=500) < 0.6)
    host = fm.equilibrium_readings_host(p, tx, ty)
    assert isinstance(host, np.ndarray) and host.shape == (500, 2)
    np.testing.assert_allclose(host, np.asarray(fm.equilibrium_readings(p, tx, ty)), atol=1e-11)
    assert np.ptp(host) > 500.0  # the tilts move the readings by hundreds of pixels
    one = fm.equilibrium_readings_host(p, 0.05, -0.02)
    np.testing.assert_allclose(one, np.asarray(fm.equilibrium_readings(p, 0.05, -0.02)), atol=1e-11)
    assert one.shape == (2,)
