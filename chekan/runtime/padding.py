"""Shape buckets: a record laid out for a structure a little larger than its own, so that
the programs of one bucket share one compiled engine (:mod:`chekan.runtime.engine`), for
``map`` and ``bayes`` alike. Padding is exact (:meth:`chekan.joint.layout.RecordModel.pad`).

Every padded size (holds H, bins N, slew samples per hold M, systematic angle-error terms S,
X-response terms X) is rounded up to the next rung of :data:`LADDER`: multiples of 8 up to
32, then five rungs per octave, 2ᵏ·{1, 9/8, 10/8, 12/8, 14/8} (at most 20 % more: warm runs
stay as fast, measured in ``docs/commands.md``). The rungs hold the real programs' sizes
where they fall (H, N, M, S, X): the paper's 9 h program and its 3 h version
(36, 216, 24, 35, 0) → (36, 224, 24, 36, 0); the designer's 9 h xy program
(160, 800, 24, 31, 21) → (160, 896, 24, 32, 24) and its 2.6 h version
(48, 240, 24, 31, 21) → (48, 256, 24, 32, 24). 0 stays 0 (no systematic or X terms is a
different model, not a smaller one). The drift and encoder degrees are not padded: their
columns are reported (the drift coefficients, the drift curve), so they stay in the key.

Two rules make more programs share: every size is at least :data:`SMALLEST`'s (short
programs share one small bucket), and a record whose own bucket lies within
:data:`DEFAULT_REACH` of one of the :data:`DEFAULT_BUCKETS` (the ones ``chekan warmup``
compiles), or is the smallest, takes that one: a 3-angle program of 32 holds and 160 bins
runs in the paper's bucket, and so do a short program and the first round of the
designer's xy program (9 holds about Y) that the live page fits, so that their first run
after the set-up loads instead of compiling.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

if TYPE_CHECKING:
    from chekan.joint.layout import ModelStructure, RecordModel

__all__ = [
    "DEFAULT_BUCKETS",
    "LADDER",
    "SMALLEST",
    "Bucket",
    "bucket_of",
    "padded_for",
    "padded_shape",
    "rung",
    "split_keys",
]

#: the rungs below 32; above it 2ᵏ·(8, 9, 10, 12, 14)/8
_LOW = (8, 16, 24, 32)
_STEPS = (9, 10, 12, 14, 16)


def _ladder(top: int = 1 << 16) -> tuple[int, ...]:
    out, base = list(_LOW), 32
    while base < top:
        out.extend(base * s // 8 for s in _STEPS)
        base *= 2
    return tuple(out)


LADDER = _ladder()


def rung(n: int) -> int:
    """The smallest rung of :data:`LADDER` ≥ ``n`` (0 for 0)."""
    if n <= 0:
        return 0
    return next(r for r in LADDER if r >= n)


class Bucket(NamedTuple):
    """A padded shape: holds, bins, slew samples per hold, systematic and X-response terms."""

    n_holds: int
    n_bins: int
    n_moves: int
    n_systematic: int
    n_x_response: int


#: The buckets of the default programs, which ``chekan warmup`` compiles (the paper's 9 h
#: program and its 3 h version; the designer's 2.6 h and 9 h xy programs)
DEFAULT_BUCKETS = (
    Bucket(36, 224, 24, 36, 0),
    Bucket(48, 256, 24, 32, 24),
    Bucket(160, 896, 24, 32, 24),
)
#: How much larger than its own bucket (holds, bins) a default bucket may be and still take
#: a record: a warm run costs at most about twice its own (tenths of a second), a first
#: run's compile a minute or more (measured in ``docs/commands.md``)
DEFAULT_REACH = 2.0
#: The smallest bucket: short programs (a few holds, tens of bins) whose kinds of terms no
#: default bucket has all share it; a size of 0 stays 0 (no systematic or X terms is a
#: different model)
SMALLEST = Bucket(16, 96, 24, 24, 24)


def bucket_of(structure: ModelStructure) -> Bucket:
    """The bucket that ``structure`` is padded to: the smallest of :data:`DEFAULT_BUCKETS`
    that holds it, has its terms (systematic, X) or lacks them as it does and has at most
    :data:`DEFAULT_REACH` times its own bucket's holds and bins (any, where its own bucket
    has :data:`SMALLEST`'s: a short record's warm run costs about twice its own, its
    compile 50–60 s); else its own bucket (each size at its rung, and at least
    :data:`SMALLEST`'s)."""
    s = structure
    sizes = (s.n_holds, s.n_bins, s.n_moves, s.n_systematic, s.n_x_response)
    own = Bucket(*(max(rung(n), low) if n else 0 for n, low in zip(sizes, SMALLEST, strict=True)))
    short = (own.n_holds, own.n_bins) == (SMALLEST.n_holds, SMALLEST.n_bins)
    for b in DEFAULT_BUCKETS:
        fits = all(x >= y for x, y in zip(b, own, strict=True))
        same_terms = (b.n_systematic > 0) == (own.n_systematic > 0) and (b.n_x_response > 0) == (
            own.n_x_response > 0
        )
        near = short or (
            b.n_holds <= DEFAULT_REACH * own.n_holds and b.n_bins <= DEFAULT_REACH * own.n_bins
        )
        if fits and same_terms and near:
            return b
    return own


def padded_shape(models: list[RecordModel]) -> Bucket:
    """The bucket that holds every model (their largest sizes, each rounded up to its rung)."""
    sizes = [bucket_of(m.structure) for m in models]
    return Bucket(*(max(col) for col in zip(*sizes, strict=True)))


def padded_for(model: RecordModel) -> RecordModel:
    """``model`` as ``map`` and ``bayes`` run it (one engine for both): padded to its bucket
    (exact: the padding carries zero weight; the per-hold and per-bin outputs of ``bayes``
    are cut back to the real holds and bins, :func:`chekan.fit.sampling.reported_draws`)."""
    return model.pad(*bucket_of(model.structure))


#: The fewest keys :func:`split_keys` splits at once (the importance path's most points)
KEYS_AT_ONCE = 8192


def split_keys(key, n: int):
    """``jax.random.split(key, n)`` as a NumPy array, split at a bucketed count
    (:data:`KEYS_AT_ONCE`, doubled until it holds ``n``) and cut to ``n``: the same keys
    (JAX's partitionable threefry, its default, splits key i alike for any count ≥ i; a
    test shows it) from one compiled split, where a count of its own compiled one for every
    number of draws (0.16 s each, and an entry in the persistent cache for every count ever
    drawn)."""
    import jax
    import numpy as np

    size = KEYS_AT_ONCE
    while size < n:
        size *= 2
    return np.asarray(jax.random.split(key, size))[:n]  # cut on the host: no slice to compile
