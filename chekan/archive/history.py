r"""Scale-factor stability history of one gravimeter, from the archive.

For each parameter (``b1``, ``b2``, ``a``, …) one value per calibration session is taken
(method ``bayes`` > ``map`` > ``classical`` per input, or the one asked for; of several
software versions the latest archived) and:

* the change between consecutive verifications and its significance
  :math:`\Delta_i = y_{i+1}-y_i,\; z_i = \Delta_i/\sqrt{s_i^2+s_{i+1}^2}`
  (also in ppm of :math:`y_i`);
* a Bayesian model of the history, in ppm of the weighted mean :math:`\bar y`
  (:math:`\tilde y = 10^6 (y-\bar y)/|\bar y|`), time :math:`\tau` in years since the first
  session :math:`t_0`:

  .. math::

     y_i = b_0 + r\,\tau_i + w(\tau_i) + e_i,\qquad
     e_i \sim N(0,\, s_i^2 + \sigma_x^2),\qquad
     \operatorname{Cov}[w(\tau), w(\tau')] = q\,\min(\tau, \tau')

  — a linear trend :math:`r` (ppm/yr), a random walk (Brownian motion, :math:`w(t_0)=0`,
  diffusion :math:`q` ppm²/yr) and the reported measurement error :math:`s_i` plus an
  optional extra per-session error :math:`\sigma_x`. With a flat prior on
  :math:`\beta=(b_0, r)` and :math:`\Sigma = qK + \mathrm{diag}(s^2+\sigma_x^2)`,
  :math:`K_{ij} = \min(\tau_i, \tau_j)`,
  :math:`H=[1,\tau]`, :math:`A = H^\top\Sigma^{-1}H`, the hyperparameters maximise the
  closed-form (restricted) marginal likelihood

  .. math::

     \log p(y\mid q,\sigma_x) = -\tfrac12 (y-H\hat\beta)^\top\Sigma^{-1}(y-H\hat\beta)
       - \tfrac12\log|\Sigma| - \tfrac12\log|A| + \text{const},\qquad
     \hat\beta = A^{-1}H^\top\Sigma^{-1}y

  (a log-grid, then L-BFGS-B on ``jax.value_and_grad``, within
  :math:`10^{-6}\ldots10^{3}` times the median :math:`s_i^2` for :math:`q` and
  :math:`\sigma_x^2`). Given them, the posterior is
  Gaussian: :math:`r \sim N(\hat\beta_1, (A^{-1})_{11})` and the scale at :math:`\tau_*`
  (Rasmussen & Williams eq. 2.41)

  .. math::

     \mathrm E[b(\tau_*)] = h_*^\top\hat\beta + k_*^\top\Sigma^{-1}(y - H\hat\beta),\quad
     \mathrm{Var} = q\tau_* - k_*^\top\Sigma^{-1}k_* + R^\top A^{-1} R,\quad
     R = h_* - H^\top\Sigma^{-1}k_*,

  :math:`k_* = q\min(\tau,\tau_*)`, :math:`h_* = (1,\tau_*)`: the true scale, without
  measurement error; the interval is :math:`\pm z\sqrt{\mathrm{Var}}` at ``hdi_prob``.
  Hyperparameter uncertainty is not propagated (empirical Bayes). Before :math:`t_0` the
  random walk is taken as zero. Fewer than 4 sessions: :math:`q=\sigma_x=0` (weighted
  straight line); one session: no trend, the prediction is that session.

Decision rule (:data:`DECISION_RULE`; ISO/IEC 17025 §7.8.6, ILAC-G8:09/2019 guarded
acceptance, guard band w = U): scale factors only (unit mGal/pix), for |Δ| the change between
consecutive verifications, or the predicted value at the requested date against the last
verification, with U its expanded uncertainty at ``hdi_prob`` (z·sd):

* ALARM when |Δ| − U > T (``tolerance_ppm``): beyond the tolerance even at the near end of
  its interval, so the change is also significant;
* WARNING when |Δ| > T otherwise (beyond the tolerance, but not by more than its U:
  inconclusive), and for a prediction also when only its interval reaches past T;
* nothing else.

With sessions on one date only there is no trend, and a prediction at another date is the
last value with an unknown (infinite) uncertainty, and no alarm: one verification cannot tell
how the scale changes, and a finite interval would be false. Otherwise the prediction's
interval grows with the distance from the sessions (the trend's and the random walk's
variance, :meth:`HistoryFit.predict`).

Sign of a (the quadratic coefficient): every value of ``a`` here is in the record's
convention (readings grow with gravity, Δg = b(m − m_h) + a(m − m_h)², eq. 8). A legacy
protocol prints a in its own convention (increments counted positive when gravity decreases,
``docs/specs/legacy-protocol.md``), which has the opposite sign; its re-analysis reports a
in the record's convention (:func:`chekan.classical.fit.increments_from_protocol`): protocol
no. 46's printed +78 nGal/pix² is archived as −7.8e-5 mGal/pix² (its printed δg are
reproduced only with that reading). Eq. (10), a = g/2K², is positive in the record's
convention (+1.34e-4 mGal/pix² for K = 60 428, the simulator's value), so histories that mix
protocols and records can show a change of sign of a: it is the instruments', not a units
slip.
"""

from __future__ import annotations

import datetime as _dt
import itertools
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from chekan.errors import ChekanError
from chekan.runtime import cached, jit

METHOD_PREFERENCE = ("bayes", "map", "classical")
DEFAULT_PARAMS = ("b1", "b2", "a")
SCALE_UNIT = "mGal/pix"
DAYS_PER_YEAR = 365.25
DECISION_RULE = (
    "guarded (ILAC-G8, guard band w = U at the interval probability): ALARM when |Δ| − U "
    "exceeds the tolerance; WARNING when |Δ| does but not by more than U (inconclusive), or "
    "when a prediction's interval reaches past it"
)
_BOUNDS = (1e-6, 1e3)  # hyperparameters, in units of the median s_i²
_GRID = 15
_NQ = 64  # prediction dates per compiled call
_PAD = 16  # sessions are padded to a multiple of this (fewer compiles)


# ----------------------------------------------------------------------------- the model
@dataclass
class HistoryFit:
    """Fitted scale-history model, in ppm of ``ref`` (``scale = |ref|``), τ in years."""

    tau: np.ndarray
    y: np.ndarray
    s: np.ndarray
    q: float  # random-walk diffusion, ppm²/yr
    sigma_x: float  # extra per-session error, ppm
    beta: np.ndarray  # (b0 ppm, r ppm/yr)
    beta_cov: np.ndarray
    log_marginal: float
    estimated: bool  # hyperparameters fitted (else fixed at 0)

    @property
    def rate(self) -> tuple[float, float]:
        """Trend r and its sd, ppm/yr."""
        return float(self.beta[1]), float(math.sqrt(self.beta_cov[1, 1]))

    def predict(self, tau_q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean and sd of the true scale b(τ) (ppm) at ``tau_q`` (years)."""
        tq = np.atleast_1d(np.asarray(tau_q, dtype=float))
        d = _padded(self.tau, self.y, self.s**2)
        means, sds = [], []
        for i in range(0, tq.size, _NQ):  # fixed query size: one compile
            chunk = np.zeros(_NQ)
            part = tq[i : i + _NQ]
            chunk[: part.size] = part
            post = _compiled()["posterior"](d, self.q, self.sigma_x**2, chunk)
            means.append(np.asarray(post["mean"])[: part.size])
            sds.append(np.sqrt(np.clip(np.asarray(post["var"])[: part.size], 0.0, None)))
        return np.concatenate(means), np.concatenate(sds)


def _jax():
    import jax
    import jax.numpy as jnp
    import jax.scipy.linalg as jsl

    import chekan.jaxconfig  # noqa: F401  (float64 before any array)

    return jax, jnp, jsl


def _padded(tau: np.ndarray, y: np.ndarray, s2: np.ndarray) -> tuple[np.ndarray, ...]:
    """``(τ, y, s², mask)`` padded to a multiple of :data:`_PAD` (one compile per size).

    A padded entry has τ = y = 0, s² = 1, mask 0: it adds a unit diagonal to Σ, a zero row to
    H and nothing to the likelihood.
    """
    n = tau.size
    size = -(-n // _PAD) * _PAD
    out = [np.zeros(size), np.zeros(size), np.ones(size), np.zeros(size)]
    for a, v in zip(out, (tau, y, s2, np.ones(n)), strict=True):
        a[:n] = v
    return tuple(out)


def _gls(d, q, v):
    """Cholesky of Σ, whitened H and y, A = HᵀΣ⁻¹H, β̂ and the restricted log-likelihood."""
    _, jnp, jsl = _jax()
    tau, y, s2, m = d
    S = q * jnp.minimum(tau[:, None], tau[None, :]) * (m[:, None] * m[None, :])
    S = S + jnp.diag(m * (s2 + v) + (1.0 - m))
    L = jnp.linalg.cholesky(S)
    H = jnp.stack([m, m * tau], axis=1)
    Y = jsl.solve_triangular(L, y * m, lower=True)
    G = jsl.solve_triangular(L, H, lower=True)
    A = G.T @ G
    cA = jnp.linalg.cholesky(A)
    beta = jsl.cho_solve((cA, True), G.T @ Y)
    r = Y - G @ beta
    ll = (
        -0.5 * r @ r
        - jnp.sum(jnp.log(jnp.diag(L)))
        - jnp.sum(jnp.log(jnp.diag(cA)))
        - 0.5 * (jnp.sum(m) - 2) * jnp.log(2 * jnp.pi)
    )
    return L, G, cA, beta, r, ll


def _neg_ll(logp, d, extra):
    """−log p(y | q, σ_x²) at ``logp = (log q, log σ_x²)``; σ_x = 0 unless ``extra``."""
    _, jnp, _ = _jax()
    q = jnp.exp(logp[0])
    v = jnp.where(extra, jnp.exp(logp[1]), 0.0)
    return -_gls(d, q, v)[-1]


def _posterior(d, q, v, tq):
    """β̂, Cov β = A⁻¹, log-likelihood and the posterior of b at ``tq`` (module docstring)."""
    _, jnp, jsl = _jax()
    L, G, cA, beta, r, ll = _gls(d, q, v)
    tau, m = d[0], d[3]
    tqc = jnp.maximum(tq, 0.0)
    V = jsl.solve_triangular(
        L, q * jnp.minimum(tau[:, None], tqc[None, :]) * m[:, None], lower=True
    )
    Hq = jnp.stack([jnp.ones_like(tq), tq], axis=1)
    mean = Hq @ beta + V.T @ r
    R = Hq.T - G.T @ V
    var = q * tqc - jnp.sum(V**2, axis=0) + jnp.sum(R * jsl.cho_solve((cA, True), R), axis=0)
    beta_cov = jsl.cho_solve((cA, True), jnp.eye(2))
    return {"beta": beta, "beta_cov": beta_cov, "ll": ll, "mean": mean, "var": var}


@cached
def _compiled() -> dict[str, Any]:
    """The two jitted kernels (compiled once per padded size; compiling dominates run time)."""
    jax, _, _ = _jax()
    return {
        "value_and_grad": jit(jax.value_and_grad(_neg_ll), static_argnums=2),
        "posterior": jit(_posterior),
    }


def fit_history(
    tau: np.ndarray,
    y: np.ndarray,
    s: np.ndarray,
    *,
    extra_error: bool = True,
    q: float | None = None,
    sigma_x: float | None = None,
) -> HistoryFit:
    """Fit the model of the module docstring to (τ years, y ppm, s ppm); n ≥ 2 distinct τ.

    Hyperparameters: best point of a log-grid, refined by L-BFGS-B on ``jax.value_and_grad``
    of the restricted marginal likelihood, within the bounds of the module docstring;
    ``q`` and ``sigma_x`` given: both held at those values instead.
    """
    from scipy.optimize import minimize

    k = _compiled()
    tau, y, s = (np.asarray(a, dtype=float) for a in (tau, y, s))
    if np.unique(tau).size < 2:
        raise ChekanError("a trend needs sessions on at least two dates")
    d = _padded(tau, y, s**2)
    if q is not None and sigma_x is not None:
        fixed, v, q = True, float(sigma_x) ** 2, float(q)
    else:
        fixed, v, q = False, 0.0, 0.0
    estimated = tau.size >= 4 and not fixed
    if estimated:
        med = float(np.median(s**2))
        lo, hi = math.log(_BOUNDS[0] * med), math.log(_BOUNDS[1] * med)
        g = np.linspace(lo, hi, _GRID)
        grid = np.stack(np.meshgrid(g, g if extra_error else [lo]), -1).reshape(-1, 2)

        def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
            val, grad = k["value_and_grad"](x, d, extra_error)
            return float(val), np.asarray(grad, dtype=float)

        f = np.array([fun(x)[0] for x in grid])
        x0 = grid[int(np.argmin(np.where(np.isfinite(f), f, np.inf)))]

        bounds = [(lo, hi), (lo, hi) if extra_error else (lo, lo)]
        opt = minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=bounds)
        x = opt.x if np.all(np.isfinite(opt.x)) and opt.fun <= fun(x0)[0] else x0
        q = math.exp(x[0])
        v = math.exp(x[1]) if extra_error else 0.0
    post = k["posterior"](d, q, v, np.zeros(_NQ))
    return HistoryFit(
        tau=tau,
        y=y,
        s=s,
        q=q,
        sigma_x=math.sqrt(v),
        beta=np.asarray(post["beta"]),
        beta_cov=np.asarray(post["beta_cov"]),
        log_marginal=float(post["ll"]),
        estimated=estimated,
    )


# ----------------------------------------------------------------------------- the data
@dataclass
class Point:
    session_id: int
    date: str
    method: str
    mean: float
    sd: float
    hdi_low: float | None
    hdi_high: float | None
    input_path: str


def select_points(
    rows: list[dict], params: tuple[str, ...], method: str | None = None
) -> tuple[dict[str, list[Point]], list[str]]:
    """One value per input and parameter from :meth:`Archive.parameter_rows` rows.

    Per input (SHA-256) the method is ``method`` or the first of
    :data:`METHOD_PREFERENCE` present, and of its software versions the latest archived.
    Undated sessions and values without an sd (held fixed) are left out, with a note.
    """
    by_input: dict[str, dict[int, list[dict]]] = {}
    for r in rows:
        by_input.setdefault(r["input_sha256"], {}).setdefault(r["session_id"], []).append(r)
    notes: list[str] = []
    out: dict[str, list[Point]] = {p: [] for p in params}
    rank = {m: i for i, m in enumerate(METHOD_PREFERENCE)}
    for sessions in by_input.values():
        cands = [(sid, rs) for sid, rs in sessions.items() if method in (None, rs[0]["method"])]
        if not cands:
            continue
        sid, rs = min(cands, key=lambda c: (rank.get(c[1][0]["method"], 99), -c[0]))
        if not rs[0]["calibrated_on"]:
            notes.append(f"session {sid} ({rs[0]['input_path']}) has no date: left out")
            continue
        named = {r["parameter"]: r for r in rs}
        for p in params:
            row = named.get(p)
            if row is None:
                continue
            if row["sd"] is None or not row["sd"] > 0:
                notes.append(f"session {sid}: {p} has no uncertainty (fixed): left out")
                continue
            out[p].append(
                Point(
                    sid,
                    row["calibrated_on"],
                    row["method"],
                    row["mean"],
                    row["sd"],
                    row["hdi_low"],
                    row["hdi_high"],
                    row["input_path"],
                )
            )
    for p in params:
        out[p].sort(key=lambda pt: (pt.date, pt.session_id))
    return out, notes


def _years(d0: _dt.date, d: _dt.date) -> float:
    return (d - d0).days / DAYS_PER_YEAR


@dataclass
class ParamHistory:
    name: str
    unit: str
    points: list[dict]
    changes: list[dict] = field(default_factory=list)
    reference: float | None = None  # ppm are relative to |reference|
    trend: dict | None = None
    model: dict | None = None
    prediction: dict | None = None
    alarms: list[dict] = field(default_factory=list)


def param_history(
    name: str,
    points: list[Point],
    unit: str,
    *,
    at: _dt.date,
    tolerance_ppm: float | None,
    hdi_prob: float = 0.95,
    extra_error: bool = True,
) -> tuple[ParamHistory, HistoryFit | None]:
    """Changes, trend, prediction at ``at`` and alarms for one parameter's points."""
    from chekan.results.document import z_for

    h = ParamHistory(name, unit, [asdict(p) for p in points])
    if not points:
        return h, None
    z = z_for(hdi_prob)
    y = np.array([p.mean for p in points])
    s = np.array([p.sd for p in points])
    w = 1.0 / s**2
    ref = float(np.sum(w * y) / np.sum(w))
    scale = abs(ref) if ref != 0 else 1.0
    h.reference = ref
    tol_ppm = tolerance_ppm if unit == SCALE_UNIT else None  # alarms for scale factors only
    for a, b in itertools.pairwise(points):
        d = b.mean - a.mean
        sd = math.hypot(a.sd, b.sd)
        ch: dict[str, Any] = {
            "from": a.date,
            "to": b.date,
            "delta": d,
            "sd": sd,
            "z": d / sd,
            "delta_ppm": d / abs(a.mean) * 1e6 if a.mean else None,
        }
        h.changes.append(ch)
        if tol_ppm is not None and ch["delta_ppm"] is not None:
            u_ppm = z * sd / abs(a.mean) * 1e6
            level = decide(abs(ch["delta_ppm"]), u_ppm, tol_ppm, interval=False)
            what = (
                f"change {a.date} → {b.date} of {ch['delta_ppm']:+.0f} ± {u_ppm:.0f} ppm "
                f"(U, {hdi_prob:.0%})"
            )
            h.alarms += _alarm(level, "change", name, what, tol_ppm, u_ppm=u_ppm, **ch)
    d0 = _dt.date.fromisoformat(points[0].date)
    tau = np.array([_years(d0, _dt.date.fromisoformat(p.date)) for p in points])
    yp = (y - ref) / scale * 1e6
    sp = s / scale * 1e6
    tau_at = _years(d0, at)
    if np.unique(tau).size < 2:  # one date: its value, and beyond it no known uncertainty
        last = points[-1]
        sd_at = last.sd if tau_at == tau[-1] else math.inf
        h.prediction = {
            "date": at.isoformat(),
            "mean": last.mean,
            "sd": sd_at,
            "hdi_prob": hdi_prob,
            "low": last.mean - z * sd_at,
            "high": last.mean + z * sd_at,
            "from_last_ppm": 0.0,
            "last_date": last.date,
        }
        return h, None
    fit = fit_history(tau, yp, sp, extra_error=extra_error)
    r, r_sd = fit.rate
    h.trend = {
        "ppm_per_year": r,
        "sd_ppm_per_year": r_sd,
        "per_year": r * scale * 1e-6,
        "sd_per_year": r_sd * scale * 1e-6,
        "z": r / r_sd if r_sd > 0 else None,
    }
    h.model = {
        "t0": points[0].date,
        "random_walk_q_ppm2_per_year": fit.q,
        "random_walk_ppm_per_sqrt_year": math.sqrt(fit.q),
        "extra_error_ppm": fit.sigma_x,
        "hyperparameters_estimated": fit.estimated,
        "log_marginal_likelihood": fit.log_marginal,
    }
    m, sd = (float(v[0]) for v in fit.predict(np.array([tau_at])))
    last = points[-1]
    mean = ref + m * scale * 1e-6
    sd_n = sd * scale * 1e-6
    h.prediction = {
        "date": at.isoformat(),
        "mean": mean,
        "sd": sd_n,
        "hdi_prob": hdi_prob,
        "low": mean - z * sd_n,
        "high": mean + z * sd_n,
        "from_last_ppm": (mean - last.mean) / abs(last.mean) * 1e6 if last.mean else None,
        "last_date": last.date,
    }
    if tol_ppm is not None and last.mean:
        pr = h.prediction
        u_ppm = z * sd_n / abs(last.mean) * 1e6
        level = decide(abs(pr["from_last_ppm"]), u_ppm, tol_ppm, interval=True)
        what = (
            f"predicted at {at.isoformat()} {pr['from_last_ppm']:+.0f} ± {u_ppm:.0f} ppm "
            f"(U, {hdi_prob:.0%}; {pr['low']:.6g} … {pr['high']:.6g}) from the last "
            f"verification ({last.date})"
        )
        h.alarms += _alarm(
            level, "prediction", name, what, tol_ppm, date=at.isoformat(), u_ppm=u_ppm
        )
    return h, fit


def _alarm(
    level: str | None, kind: str, name: str, what: str, tolerance_ppm: float, **fields
) -> list[dict]:
    """``[]`` or the one alarm of ``level`` on ``what``, in the decision rule's words."""
    if level is None:
        return []
    verdict = _verdict(level, tolerance_ppm)
    if level == "ALARM" and kind == "prediction":
        verdict += ": recalibrate"
    message = f"{name}: {what} {verdict}"
    return [{"level": level, "kind": kind, "param": name, "message": message, **fields}]


def decide(delta_ppm: float, u_ppm: float, tolerance_ppm: float, *, interval: bool) -> str | None:
    """:data:`DECISION_RULE` for |Δ| with expanded uncertainty U (ppm): ALARM when |Δ| − U > T;
    WARNING when |Δ| > T, or (``interval``: a prediction) when only |Δ| + U > T."""
    if delta_ppm - u_ppm > tolerance_ppm:
        return "ALARM"
    if delta_ppm > tolerance_ppm or (interval and delta_ppm + u_ppm > tolerance_ppm):
        return "WARNING"
    return None


def _verdict(level: str, tolerance_ppm: float) -> str:
    if level == "ALARM":
        return f"exceeds ±{tolerance_ppm:g} ppm by more than its U (guarded rule)"
    return (
        f"reaches past ±{tolerance_ppm:g} ppm, not by more than its U: inconclusive (guarded rule)"
    )


def stability_history(
    archive,
    serial: str,
    *,
    params: tuple[str, ...] = DEFAULT_PARAMS,
    method: str | None = None,
    at: _dt.date | str | None = None,
    tolerance_ppm: float | None = 500.0,
    hdi_prob: float = 0.95,
    extra_error: bool = True,
) -> dict:
    """The whole history report of ``serial`` as a dict (see :func:`format_history`).

    ``archive``: an open :class:`~chekan.archive.db.Archive`. ``at``: date of the prediction
    (default today). Everything but ``fits`` is the ``chekan-history/1`` JSON
    (:func:`write_history_json`); ``fits`` maps each parameter to its :class:`HistoryFit`,
    whose ``predict(tau_years)`` gives the posterior of the true value at any date.
    """
    from chekan.results.document import UNITS

    at = _dt.date.fromisoformat(at) if isinstance(at, str) else (at or _dt.date.today())
    rows = archive.parameter_rows(str(serial))
    if not rows:
        raise ChekanError(f"archive {archive.path}: no sessions of instrument {serial!r}")
    pts, notes = select_points(rows, tuple(params), method)
    units = {r["parameter"]: r["unit"] for r in rows}
    out: dict[str, Any] = {
        "format": "chekan-history/1",
        "serial": str(serial),
        "method": method or "preferred: " + " > ".join(METHOD_PREFERENCE),
        "at": at.isoformat(),
        "tolerance_ppm": tolerance_ppm,
        "decision_rule": DECISION_RULE,
        "hdi_prob": hdi_prob,
        "parameters": {},
        "alarms": [],
        "notes": notes,
    }
    fits = {}
    for p in params:
        if not pts[p]:
            out["notes"].append(f"no values of {p}")
            continue
        h, fits[p] = param_history(
            p,
            pts[p],
            units.get(p) or UNITS.get(p, ""),
            at=at,
            tolerance_ppm=tolerance_ppm,
            hdi_prob=hdi_prob,
            extra_error=extra_error,
        )
        if h.trend is None:
            out["notes"].append(
                f"{p}: sessions on one date only: no trend, and a prediction beyond that date "
                "has no known uncertainty (one verification cannot tell how the scale changes)"
            )
        out["parameters"][p] = asdict(h)
        out["alarms"].extend(h.alarms)
    out["fits"] = fits  # the fitted models, for plots and predictions; not written to JSON
    return out


def write_history_json(path: str | Path, hist: dict) -> Path:
    from chekan.files.durable import atomic_output
    from chekan.results.document import _clean

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = {k: v for k, v in hist.items() if k != "fits"}
    text = json.dumps(_clean(data), indent=2, ensure_ascii=False) + "\n"
    with atomic_output(path) as f:
        f.write(text)
    return path


def format_history(hist: dict) -> str:
    """Plain-text report: per parameter the sessions, changes, trend, prediction; alarms."""
    lines = [f"stability history of gravimeter {hist['serial']} ({hist['method']})"]
    for name, h in hist["parameters"].items():
        lines.append("")
        lines.append(f"{name} [{h['unit']}]")
        lines.append(f"  {'date':<10}  {'method':<9} {'mean':>12} {'sd':>10} {'Δ ppm':>9} {'z':>6}")
        for i, p in enumerate(h["points"]):
            row = f"  {p['date']:<10}  {p['method']:<9} {p['mean']:12.7g} {p['sd']:10.2e}"
            if i:
                c = h["changes"][i - 1]
                dp = c["delta_ppm"]
                row += f" {dp:+9.1f} {c['z']:+6.2f}" if dp is not None else ""
            lines.append(row)
        t, m = h["trend"], h["model"]
        if t:
            lines.append(
                f"  trend {t['ppm_per_year']:+.1f} ± {t['sd_ppm_per_year']:.1f} ppm/yr "
                f"({t['per_year']:+.3g} ± {t['sd_per_year']:.2g} {h['unit']}/yr); random walk "
                f"{m['random_walk_ppm_per_sqrt_year']:.3g} ppm/√yr, extra error "
                f"{m['extra_error_ppm']:.3g} ppm"
            )
        pr = h["prediction"]
        if pr and not (pr["sd"] is not None and math.isfinite(pr["sd"])):
            lines.append(
                f"  predicted at {pr['date']}: {pr['mean']:.7g} ± unknown (one verification "
                "date: how the value changes cannot be estimated)"
            )
        elif pr:
            lines.append(
                f"  predicted at {pr['date']}: {pr['mean']:.7g} ± {pr['sd']:.2g} "
                f"({pr['hdi_prob']:.0%}: {pr['low']:.7g} … {pr['high']:.7g}), "
                f"{pr['from_last_ppm']:+.0f} ppm from {pr['last_date']}"
            )
    if hist["alarms"]:
        lines.append("")
        lines += [f"{a['level']}: {a['message']}" for a in hist["alarms"]]
    elif hist["tolerance_ppm"] is not None:
        lines.append("")
        lines.append(f"no alarm (tolerance ±{hist['tolerance_ppm']:g} ppm)")
    if hist["tolerance_ppm"] is not None:
        lines.append(f"decision rule: {hist.get('decision_rule', DECISION_RULE)}")
    lines += [f"note: {n}" for n in hist["notes"]]
    return "\n".join(lines)


def plot_history(hist: dict, path: str | Path) -> Path:
    """Write :func:`history_figure` to ``path`` (PNG, PDF or SVG from its suffix)."""
    from chekan.files.durable import atomic_output

    fig = history_figure(hist)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path, "wb") as f:
        fig.savefig(f, dpi=120, format=path.suffix.lstrip(".").lower() or "png")
    return path


def history_figure(hist: dict):
    """One panel per parameter p: sessions ± sd, the posterior of p(t) with its band, alarms."""
    from chekan.report.plotting import new_figure

    names = list(hist["parameters"])
    fig = new_figure((9, 2.8 * max(len(names), 1)))
    axes = fig.subplots(max(len(names), 1), 1, sharex=True, squeeze=False)
    at = _dt.date.fromisoformat(hist["at"])
    z = None
    for ax, name in zip(axes[:, 0], names, strict=False):
        h = hist["parameters"][name]
        fit: HistoryFit | None = hist.get("fits", {}).get(name)
        dates = [_dt.date.fromisoformat(p["date"]) for p in h["points"]]
        ys = np.array([p["mean"] for p in h["points"]])
        ss = np.array([p["sd"] for p in h["points"]])
        ax.errorbar(dates, ys, yerr=ss, fmt="o", ms=4, capsize=2, label="session ± sd")
        if fit is not None:
            from chekan.results.document import z_for

            z = z_for(hist["hdi_prob"])
            d0 = dates[0]
            end = max(at, dates[-1])
            grid = [d0 + _dt.timedelta(days=float(x)) for x in np.linspace(0, (end - d0).days, 300)]
            tq = np.array([_years(d0, d) for d in grid])
            m, sd = fit.predict(tq)
            ref, scale = h["reference"], abs(h["reference"]) or 1.0
            mu = ref + m * scale * 1e-6
            band = z * sd * scale * 1e-6
            ax.plot(grid, mu, "C1-", lw=1, label=f"posterior of {name}(t)")
            ax.fill_between(grid, mu - band, mu + band, color="C1", alpha=0.2)
            lin = ref + (fit.beta[0] + fit.beta[1] * tq) * scale * 1e-6
            ax.plot(grid, lin, "C2--", lw=1, label="trend")
        pr = h["prediction"]
        if pr and pr["sd"] is not None and math.isfinite(pr["sd"]):  # else: no interval known
            ax.errorbar(
                [at],
                [pr["mean"]],
                yerr=[[pr["mean"] - pr["low"]], [pr["high"] - pr["mean"]]],
                fmt="s",
                color="C3",
                capsize=3,
                label=f"prediction {pr['date']}",
            )
        for a in h["alarms"]:
            if a["kind"] == "change":
                ax.axvline(_dt.date.fromisoformat(a["to"]), color="r", lw=0.8, ls=":")
        ax.set_ylabel(f"{name} [{h['unit']}]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    axes[0, 0].set_title(f"Gravimeter {hist['serial']}: scale stability")
    fig.tight_layout()
    return fig
