"""Column spans: half-open `(start, stop)` ranges of a row's columns, as layouts and manifests write them."""

from __future__ import annotations

Spans = tuple[tuple[int, int], ...]


def span_indices(spans: Spans) -> list[int]:
    """The column indices covered by `spans`, in order."""
    return [i for a, b in spans for i in range(a, b)]
