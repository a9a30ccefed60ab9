"""Which features may be used together: the fields of an extractor's identity that must match (no torch)."""

from __future__ import annotations

from cnep.perception.constants import COMPATIBILITY_FIELDS


def compatibility_key(identity: dict[str, str]) -> tuple[str, ...]:
    """The identity fields that must match for features to be mixed (COMPATIBILITY_FIELDS, as `field=value`).

    The backend and the weights' name are left out: backends run the same graph and agree to cosine
    similarity >= 0.9999 (tests/perception/test_backends.py), and equal weights have equal sha256 whatever
    their file is called. The precision is in (files without one are fp32), and for int8 the
    quantisation with its calibration frames' hash: int8 features differ from fp32 ones by ~1%.
    """
    fields = tuple(f"{field}={identity.get(field, '(missing)')}" for field in COMPATIBILITY_FIELDS)
    precision = identity.get("precision", "fp32")
    return (
        fields
        + (f"precision={precision}",)
        + ((f"quantisation={identity.get('quantisation')}",) if precision != "fp32" else ())
    )
