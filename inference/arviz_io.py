"""The only module that touches ArviZ (0.23; imported lazily: ~1.6 s and a FutureWarning).

Moving to ArviZ 1.x (InferenceData → xarray DataTree) should touch this file only. NetCDF
files written here stay readable across that move. ``hdi_prob`` is always passed explicitly
(the 1.x default changes).
"""

from __future__ import annotations

from . import _jax  # noqa: F401  (float64 before any array exists)

# isort: split

import contextlib
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    import arviz as az

__all__ = [
    "ess_bulk_array",
    "ess_tail_array",
    "hdi_array",
    "load_netcdf",
    "mcse_mean_array",
    "posterior_arrays",
    "psis_log_weights",
    "rhat_array",
    "save_netcdf",
    "summary",
    "to_inference_data",
]


def _az():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        import arviz

    return arviz


def _as_chain_draw(x: np.ndarray, what: str) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim != 2:
        raise ValueError(f"{what} needs a (chain, draw) array, got shape {x.shape}")
    return x


# --------------------------------------------------------------------------- array statistics
def rhat_array(x: np.ndarray) -> float:
    """Rank-normalised split R̂ (Vehtari et al. 2021) of a (chain, draw) array."""
    return float(_az().rhat(_as_chain_draw(x, "rhat"), method="rank"))


def ess_bulk_array(x: np.ndarray) -> float:
    """Rank-normalised bulk effective sample size of a (chain, draw) array."""
    return float(_az().ess(_as_chain_draw(x, "ess_bulk"), method="bulk"))


def ess_tail_array(x: np.ndarray) -> float:
    """Tail effective sample size (5 % and 95 % quantiles) of a (chain, draw) array."""
    return float(_az().ess(_as_chain_draw(x, "ess_tail"), method="tail"))


def mcse_mean_array(x: np.ndarray) -> float:
    """Monte-Carlo standard error of the mean of a (chain, draw) array."""
    return float(_az().mcse(_as_chain_draw(x, "mcse"), method="mean"))


def hdi_array(x: np.ndarray, hdi_prob: float) -> tuple[float, float]:
    """Highest-density interval of all draws of ``x`` (any shape, pooled)."""
    lo, hi = _az().hdi(np.asarray(x, dtype=float).reshape(-1), hdi_prob=hdi_prob)
    return float(lo), float(hi)


def psis_log_weights(log_ratios: np.ndarray) -> tuple[np.ndarray, float]:
    r"""Pareto-smoothed importance log weights, normalised (logsumexp 0), and k̂.

    ``log_ratios`` (n,): :math:`\log p(x_i) - \log q(x_i)` up to a constant; −inf where
    :math:`p(x_i) = 0` (outside the support). ``az.psislw(·, reff=1)`` (independent draws;
    Vehtari et al. 2024) smooths the finite ratios only: the points outside the support get
    weight 0 (log weight −inf) and do not count towards the tail's size, so the result is
    PSIS from q restricted to the support. Equal finite ratios (q ∝ p there) give equal
    weights and k̂ = −inf (no tail); a tail of at most 4 points (about 20 finite ratios or
    fewer), k̂ = inf; a generalised-Pareto fit that fails (non-finite smoothed weights),
    the raw normalised weights and k̂ = inf.
    """
    lr = np.asarray(log_ratios, dtype=float)
    if lr.ndim != 1:
        raise ValueError(f"psis_log_weights needs a 1-D array of log ratios, got {lr.shape}")
    if np.isnan(lr).any() or np.isposinf(lr).any():
        raise ValueError("log ratios must not be NaN or +inf")
    finite = np.isfinite(lr)
    if not finite.any():
        raise ValueError("no log ratio is finite: every point lies outside the support")
    x = lr[finite]
    out = np.full(lr.shape, -np.inf)
    if np.all(x == x[0]):
        out[finite] = -np.log(x.size)
        return out, -np.inf
    smoothed, k = _az().psislw(x, reff=1.0, normalize=True)
    smoothed, khat = np.asarray(smoothed, dtype=float), float(k)
    if not np.all(np.isfinite(smoothed)):
        smoothed = x - np.max(x)
        smoothed -= np.log(np.sum(np.exp(smoothed)))
        khat = np.inf
    out[finite] = smoothed
    return out, khat


# --------------------------------------------------------------------------- InferenceData
def to_inference_data(
    posterior: Mapping[str, np.ndarray],
    *,
    sample_stats: Mapping[str, np.ndarray] | None = None,
    observed_data: Mapping[str, np.ndarray] | None = None,
    posterior_predictive: Mapping[str, np.ndarray] | None = None,
    log_likelihood: Mapping[str, np.ndarray] | None = None,
    coords: Mapping[str, Sequence[Any]] | None = None,
    dims: Mapping[str, Sequence[str]] | None = None,
    attrs: Mapping[str, Any] | None = None,
) -> az.InferenceData:
    """InferenceData from (chain, draw, ...) arrays; ``observed_data`` has no chain/draw axes.

    ``attrs`` values must be NetCDF-storable (str, numbers, 1-D arrays of them).
    """
    az = _az()
    for group, d in (
        ("posterior", posterior),
        ("sample_stats", sample_stats),
        ("posterior_predictive", posterior_predictive),
        ("log_likelihood", log_likelihood),
    ):
        for k, v in (d or {}).items():
            if np.ndim(v) < 2:
                raise ValueError(
                    f"{group}[{k!r}] has shape {np.shape(v)}: need (chain, draw, ...) arrays"
                )
    return az.from_dict(
        posterior={k: np.asarray(v) for k, v in posterior.items()},
        sample_stats=None if sample_stats is None else dict(sample_stats),
        observed_data=None if observed_data is None else dict(observed_data),
        posterior_predictive=None if posterior_predictive is None else dict(posterior_predictive),
        log_likelihood=None if log_likelihood is None else dict(log_likelihood),
        coords=None if coords is None else dict(coords),
        dims=None if dims is None else {k: list(v) for k, v in dims.items()},
        attrs=None if attrs is None else dict(attrs),
    )


#: Room a NetCDF needs beyond its arrays (HDF5 structure, attributes), bytes.
NETCDF_OVERHEAD_BYTES = 1 << 20


def netcdf_size_bound(idata: az.InferenceData) -> int:
    """An upper bound of the NetCDF's size: every array uncompressed, plus the overhead."""
    total = NETCDF_OVERHEAD_BYTES
    for group in idata.groups():
        ds = idata[group]
        total += sum(int(v.nbytes) for v in ds.variables.values())
    return total


@contextlib.contextmanager
def _atomic_file(
    path: Path, need_bytes: int, sync_dir: Callable[[Path], None] | None
) -> Iterator[str]:
    """A temporary file beside ``path`` to write, renamed onto it (mode 0666 less the
    umask, then ``sync_dir(path)``) when the block ends well and removed whatever fails; an
    ``OSError`` (ENOSPC) before anything is written where the folder has less than
    ``need_bytes`` free (HDF5 that runs out of space mid-write can crash the process)."""
    import errno
    import os
    import shutil
    import tempfile

    path.parent.mkdir(parents=True, exist_ok=True)
    free = shutil.disk_usage(path.parent).free
    if free < need_bytes:
        raise OSError(
            errno.ENOSPC,
            f"no room for the posterior ({need_bytes / 1e6:.1f} MB needed, "
            f"{free / 1e6:.1f} MB free)",
            str(path),
        )
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        yield tmp
        umask = os.umask(0o022)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
        if sync_dir is not None:
            sync_dir(path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def save_netcdf(
    idata: az.InferenceData,
    path: str | Path,
    *,
    sync_dir: Callable[[Path], None] | None = None,
) -> Path:
    """Write ``idata`` to NetCDF (h5netcdf engine, compressed); returns the path.

    Written to a temporary file beside ``path`` and renamed into place, so an interrupted
    run leaves the old file (or none), never half a posterior; the temporary file is removed
    whatever fails. A disk without room for :func:`netcdf_size_bound` is an ``OSError``
    (ENOSPC) before anything is written: HDF5 that runs out of space mid-write can crash
    the process. ``sync_dir(path)``, if given, makes the new name durable (an fsync of the
    folder; the caller's, so that this package stays free of the domain's file layer).
    """
    path = Path(path)
    with _atomic_file(path, netcdf_size_bound(idata), sync_dir) as tmp:
        idata.to_netcdf(tmp, engine="h5netcdf")
    return path


def load_netcdf(path: str | Path) -> az.InferenceData:
    """Read an InferenceData NetCDF file written by :func:`save_netcdf`."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no InferenceData file at {path}")
    return _az().from_netcdf(str(path), engine="h5netcdf")


def posterior_arrays(
    idata: az.InferenceData, var_names: Sequence[str] | None = None
) -> dict[str, np.ndarray]:
    """The posterior group as (chain, draw, ...) NumPy arrays."""
    post = idata["posterior"]
    names = [str(n) for n in post.data_vars] if var_names is None else list(var_names)
    missing = [n for n in names if n not in post.data_vars]
    if missing:
        raise KeyError(f"posterior has no variable(s) {missing}; has {list(post.data_vars)}")
    return {n: np.asarray(post[n].transpose("chain", "draw", ...).values) for n in names}


def summary(
    idata: az.InferenceData, var_names: Sequence[str] | None, hdi_prob: float
) -> dict[str, dict[str, float]]:
    """Per flat element (``"b[1]"``): mean, sd, hdi_low, hdi_high, r_hat, ess_bulk, ess_tail,
    mcse_mean (see :func:`inference.diagnostics.summarize_draws`)."""
    from .diagnostics import summarize_draws

    return summarize_draws(posterior_arrays(idata, var_names), hdi_prob=hdi_prob)


# --------------------------------------------------------------------------- direct NetCDF
#: The groups of an InferenceData file, in ArviZ's order; all but ``observed_data`` are
#: (chain, draw, ...) arrays.
GROUPS = ("posterior", "posterior_predictive", "log_likelihood", "sample_stats", "observed_data")


def save_posterior_netcdf(
    path: str | Path,
    groups: Mapping[str, Mapping[str, np.ndarray]],
    *,
    coords: Mapping[str, Sequence[Any]] | None = None,
    dims: Mapping[str, Sequence[str]] | None = None,
    attrs: Mapping[str, Any] | None = None,
    sync_dir: Callable[[Path], None] | None = None,
) -> Path:
    """The file :func:`save_netcdf` of :func:`to_inference_data` writes, written directly
    with h5netcdf: neither ArviZ nor xarray is imported (≈ 2–3 s of a new process).

    ``groups``: ``{group: {name: array}}`` (:data:`GROUPS`). As ``az.from_dict`` lays them
    out: every group but ``observed_data`` has leading ``chain`` and ``draw`` dimensions,
    then ``dims[name]`` or ``{name}_dim_{i}``; every dimension has an integer index
    coordinate unless ``coords`` names its values; each group carries ``created_at`` and
    ``arviz_version`` (``observed_data`` also ``attrs``, the file's root ``attrs``);
    float variables with a NaN fill value, as ``InferenceData.to_netcdf``, but not
    compressed: posterior draws are noise to gzip (the 9 h record's pointwise
    log-likelihood: 5 % smaller in 12× the time, 0.59 s against 0.05 s); integers are.
    Atomic like :func:`save_netcdf` (temporary file renamed into place; ENOSPC first).
    """
    import datetime
    from importlib.metadata import version

    import h5netcdf
    import h5py

    unknown = set(groups) - set(GROUPS)
    if unknown:
        raise ValueError(f"unknown InferenceData group(s) {sorted(unknown)}")
    coords, dims, attrs = dict(coords or {}), dict(dims or {}), dict(attrs or {})
    path = Path(path)
    need = NETCDF_OVERHEAD_BYTES + sum(
        np.asarray(v).nbytes for g in groups.values() for v in g.values()
    )
    az_version = version("arviz")
    with _atomic_file(path, need, sync_dir) as tmp, h5netcdf.File(tmp, "w") as f:
        f.attrs.update(attrs)
        for group in GROUPS:
            if group not in groups:
                continue
            g = f.create_group(group)
            sampled = group != "observed_data"
            named: dict[str, int] = {}
            variables = []
            for name, value in groups[group].items():
                a = np.asarray(value)
                lead = ["chain", "draw"] if sampled else []
                if sampled and a.ndim < 2:
                    raise ValueError(f"{group}[{name!r}] needs (chain, draw, ...) arrays")
                rest = list(dims.get(name, []))
                rest += [f"{name}_dim_{i}" for i in range(len(rest), a.ndim - len(lead))]
                names = lead + rest
                for d, n in zip(names, a.shape, strict=True):
                    if named.setdefault(d, n) != n:
                        raise ValueError(f"{group}: dimension {d!r} has sizes {named[d]}, {n}")
                variables.append((name, names, a))
            for d, n in named.items():
                g.dimensions[d] = n
                values = np.asarray(coords[d]) if d in coords else np.arange(n)
                if values.dtype.kind in "OUS":  # text: variable-length strings
                    g.create_variable(
                        d, (d,), data=values.astype(object), dtype=h5py.string_dtype()
                    )
                else:
                    g.create_variable(d, (d,), data=values, compression="gzip")
            for name, names, a in variables:
                kw = {"compression": "gzip"} if a.dtype.kind in "iub" else {}
                fill = {"fillvalue": np.nan} if a.dtype.kind == "f" else {}
                g.create_variable(name, tuple(names), data=a, **kw, **fill)
            g.attrs["created_at"] = datetime.datetime.now(datetime.UTC).isoformat()
            g.attrs["arviz_version"] = az_version
            if group == "observed_data":
                g.attrs.update(attrs)
    return path
