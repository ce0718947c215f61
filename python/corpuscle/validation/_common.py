"""Helpers the SPH validations share."""

from __future__ import annotations


BACKENDS = ("serial", "cpu", "cuda")


def sph_indexes() -> tuple[str, ...]:
    """The SPH kinds' neighbour searches as the core lists them, the default first."""
    from .. import _core

    return tuple(dict(_core.kinds())["dam-break"])


def add_engine(parser, default_backend: str = "cpu") -> None:
    parser.add_argument("--backend", choices=BACKENDS, default=default_backend,
                        help=f"compute backend (default: {default_backend})")
    indexes = sph_indexes()
    parser.add_argument("--neighbors", choices=indexes, default=indexes[0],
                        help=f"neighbour search (default: {indexes[0]}, as the scenes run)")
    parser.add_argument("--device", type=int, default=0, help="CUDA device (default: 0)")


def positive_int(name: str, value) -> int | None:
    if value is None:
        return None
    try:
        v = int(str(value).strip())
    except ValueError:
        raise ValueError(f"{name} must be a positive integer, got {value!r}") from None
    if v < 1:
        raise ValueError(f"{name} must be a positive integer, got {v}")
    return v
