"""A batch in fixed-size chunks, one thread per core: a compiled function sees one shape."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax
import numpy as np


def map_chunks(
    fn: Callable[..., Any], args: Sequence[Any], size: int, threads: int | None = None
) -> Any:
    """``fn(*chunk)`` over consecutive chunks of ``size`` rows of every array in ``args``
    (the last chunk padded by repeating its last row, so a compiled ``fn`` sees one shape);
    the outputs (a pytree of arrays, rows on the leading axis) trimmed to the rows given
    and joined. The chunks run on ``threads`` threads (default: one per core, never more
    than chunks; one chunk runs in the calling thread): a compiled call releases the GIL,
    and each row's value is the same for any number of threads."""
    n = len(args[0])
    starts = range(0, n, size)

    def one(i: int) -> Any:
        k = min(size, n - i)
        chunk = [
            np.concatenate(
                [
                    np.asarray(a[i : i + k]),
                    np.repeat(np.asarray(a[i + k - 1 : i + k]), size - k, axis=0),
                ]
            )
            for a in args
        ]
        return jax.tree_util.tree_map(lambda x: np.asarray(x)[:k], fn(*chunk))

    workers = min(len(starts), threads or os.cpu_count() or 1)
    if workers <= 1:
        parts = [one(i) for i in starts]
    else:
        with ThreadPoolExecutor(workers, thread_name_prefix="chunks") as pool:
            parts = list(pool.map(one, starts))
    return jax.tree_util.tree_map(lambda *p: np.concatenate(p), *parts)
