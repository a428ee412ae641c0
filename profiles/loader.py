"""Find and read profile TOML files, and check their fields with one-line errors."""

from __future__ import annotations

import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

KINDS = ("robots", "drives", "benches", "effects", "experiments", "formats")
_SINGULAR = {"benches": "bench", "effects": "effects"}  # the rest: drop the s

_MISSING = object()


class ProfileError(ValueError):
    """A profile that cannot be used. ``str()`` is one line: ``FILE: field 'X': what is wrong``."""

    def __init__(self, source: str, field: str | None, message: str) -> None:
        self.source = source
        self.field = field
        self.message = message
        where = f"{source}: field {field!r}" if field else source  # repr: one line, always
        super().__init__(f"{where}: {message}")


def _package_dir(kind: str) -> Path:
    return Path(str(resources.files("profiles").joinpath(kind)))


def available(kind: str) -> list[str]:
    """Names of the profiles of ``kind`` shipped with the package."""
    if kind not in KINDS:
        raise ValueError(f"unknown profile kind {kind!r}; one of {', '.join(KINDS)}")
    return sorted(p.stem for p in _package_dir(kind).glob("*.toml"))


def resolve(kind: str, name_or_path: str | Path) -> Path:
    """Path of the shipped profile ``name_or_path``, or ``name_or_path`` itself if it is a file."""
    candidate = Path(name_or_path)
    if candidate.suffix == ".toml" or candidate.is_file() or len(candidate.parts) > 1:
        if not candidate.is_file():
            raise ProfileError(str(candidate), None, "no such profile file")
        return candidate
    shipped = _package_dir(kind) / f"{name_or_path}.toml"
    if not shipped.is_file():
        names = ", ".join(available(kind)) or "none"
        raise ProfileError(
            f"{kind}/{name_or_path}",
            None,
            f"no {_SINGULAR.get(kind, kind[:-1])} profile of that name (shipped: {names})",
        )
    return shipped


def load_toml(kind: str, name_or_path: str | Path) -> tuple[dict[str, Any], str]:
    """Read a profile; returns (data, source) where source is the path used in error messages."""
    path = resolve(kind, name_or_path)
    source = str(path)
    try:
        with open(path, "rb") as f:
            return tomllib.load(f), source
    except (ValueError, RecursionError) as exc:
        # TOMLDecodeError, and what tomllib lets through: UnicodeDecodeError (not UTF-8),
        # ValueError (an integer of more than 4300 digits), RecursionError (arrays nested deep)
        raise ProfileError(source, None, f"not valid TOML: {exc}") from None
    except OSError as exc:
        raise ProfileError(source, None, f"cannot read: {exc.strerror}") from None


class Fields:
    """Typed, checked access to one profile table; errors name the file and the dotted field."""

    def __init__(self, data: dict[str, Any], source: str, prefix: str = "") -> None:
        if not isinstance(data, dict):
            raise ProfileError(source, prefix.rstrip(".") or None, "must be a table")
        self.data = data
        self.source = source
        self.prefix = prefix

    def error(self, key: str, message: str) -> ProfileError:
        return ProfileError(self.source, self.prefix + key, message)

    def _get(self, key: str, default: Any) -> Any:
        if key in self.data:
            return self.data[key]
        if default is _MISSING:
            raise self.error(key, "missing")
        return default

    def keys(self) -> list[str]:
        return list(self.data)

    def has(self, key: str) -> bool:
        return key in self.data

    def table(self, key: str, default: Any = _MISSING) -> Fields:
        value = self._get(key, default)
        if not isinstance(value, dict):
            raise self.error(key, f"must be a table, got {_describe(value)}")
        return Fields(value, self.source, f"{self.prefix}{key}.")

    def tables(self, key: str) -> list[Fields]:
        value = self._get(key, _MISSING)
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise self.error(key, f"must be an array of tables, got {_describe(value)}")
        return [Fields(v, self.source, f"{self.prefix}{key}[{i}].") for i, v in enumerate(value)]

    def string(self, key: str, default: Any = _MISSING) -> str:
        value = self._get(key, default)
        if not isinstance(value, str):
            raise self.error(key, f"must be a string, got {_describe(value)}")
        return value

    def boolean(self, key: str, default: Any = _MISSING) -> bool:
        value = self._get(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"must be true or false, got {_describe(value)}")
        return value

    def integer(
        self, key: str, default: Any = _MISSING, *, lo: int | None = None, hi: int | None = None
    ) -> int:
        value = self._get(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"must be an integer, got {_describe(value)}")
        _check_range(self, key, value, lo, hi)
        return value

    def number(
        self,
        key: str,
        default: Any = _MISSING,
        *,
        lo: float | None = None,
        hi: float | None = None,
        positive: bool = False,
    ) -> float:
        value = self._get(key, default)
        return _as_number(self, key, value, lo, hi, positive)

    def numbers(
        self,
        key: str,
        n: int,
        default: Any = _MISSING,
        *,
        lo: float | None = None,
        hi: float | None = None,
        positive: bool = False,
    ) -> tuple[float, ...]:
        value = self._get(key, default)
        if not isinstance(value, list | tuple) or len(value) != n:
            raise self.error(key, f"must be a list of {n} numbers, got {_describe(value)}")
        return tuple(
            _as_number(self, f"{key}[{i}]", v, lo, hi, positive) for i, v in enumerate(value)
        )

    def strings(self, key: str, n: int, default: Any = _MISSING) -> tuple[str, ...]:
        value = self._get(key, default)
        if (
            not isinstance(value, list)
            or len(value) != n
            or not all(isinstance(v, str) for v in value)
        ):
            raise self.error(key, f"must be a list of {n} strings, got {_describe(value)}")
        return tuple(value)

    def only(self, allowed: set[str] | list[str] | tuple[str, ...], what: str = "field") -> None:
        """Reject keys not in ``allowed`` (typos should not be silently ignored)."""
        for key in self.data:
            if key not in allowed:
                raise self.error(
                    key, f"unknown {what}; expected one of {', '.join(sorted(allowed))}"
                )


def _describe(value: Any) -> str:
    if value is _MISSING:
        return "nothing"
    text = repr(value)
    if len(text) > 40:
        text = text[:37] + "..."
    return f"{type(value).__name__} {text}"


def _check_range(f: Fields, key: str, value: float, lo: float | None, hi: float | None) -> None:
    if lo is not None and value < lo:
        raise f.error(key, f"must be >= {lo}, got {value}")
    if hi is not None and value > hi:
        raise f.error(key, f"must be <= {hi}, got {value}")


# The largest magnitude of a profile number without a range of its own. Profile numbers are SI
# quantities of an arm, a drive, a bench or an effect (kg, m, kg m², Nm, s, rad); none of any
# real one comes near 1e9. Bounded so, the quantities derived from them (θ = m·lc² + I,
# g·m·lc, the plant's det M = θ1·θ3 − θ2², a cogging torque over an inertia) stay finite in
# float64 (products of three fields: 1e27; their squares: 1e54), where 1e300 overflowed into
# OverflowError tracebacks in simulate, identify and diagnose. Not tuned: any bound between
# "beyond any arm" and "overflows when multiplied" would do.
MAX_PROFILE_MAGNITUDE = 1e9


def _as_number(
    f: Fields, key: str, value: Any, lo: float | None, hi: float | None, positive: bool
) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise f.error(key, f"must be a number, got {_describe(value)}")
    try:
        value = float(value)
    except OverflowError:  # tomllib reads integers of any size
        raise f.error(key, f"must be finite, got {_describe(value)}") from None
    if not math.isfinite(value):
        raise f.error(key, f"must be finite, got {value}")
    if positive and value <= 0:
        raise f.error(key, f"must be > 0, got {value}")
    _check_range(f, key, value, lo, hi)
    if abs(value) > MAX_PROFILE_MAGNITUDE:
        raise f.error(
            key,
            f"{value:g} is out of range (|value| <= {MAX_PROFILE_MAGNITUDE:g} in SI units: "
            "beyond any arm or bench, and what is derived from it would overflow)",
        )
    return value


__all__ = [
    "KINDS",
    "MAX_PROFILE_MAGNITUDE",
    "ProfileError",
    "available",
    "load_toml",
    "resolve",
]
