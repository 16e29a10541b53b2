"""Shape buckets: a record laid out for a structure a little larger than its own, so that
records of similar size share one compiled executable (padding carries zero weight)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from chekan.joint.layout import RecordModel

__all__ = ["padded_for", "padded_shape"]


def padded_shape(models: list[RecordModel]) -> tuple[int, int, int, int]:
    """(H, N, M, S) that holds every model, rounded up (H and S to 4, N and M to 16) so
    that chunks of similar records share one compiled solver."""

    def up(x: int, m: int) -> int:
        return -(-x // m) * m

    H = max(m.structure.n_holds for m in models)
    N = max(m.structure.n_bins for m in models)
    M = max(m.structure.n_moves for m in models)
    S = max(m.structure.n_systematic for m in models)
    return up(H, 4), up(N, 16), up(M, 16), up(S, 4)


def padded_for(model: RecordModel, method: str) -> RecordModel:
    """``model`` as ``method`` runs it: ``map`` pads it to its shape bucket (exact: padding
    carries zero weight), so that records of similar size share one compiled solver;
    ``bayes`` keeps the record's own shape (its per-hold outputs would carry the padding)."""
    return model.pad(*padded_shape([model])) if method == "map" else model
