"""Parameter files: what `hil identify` writes and `hil control --params` / `hil diagnose --params`
read.

A parameter file is JSON (``params.json``)::

    {"kind": "ddbench parameters", "robot": "cicese", "selected": "filtered_dynamic",
     "schemes": {"filtered_dynamic": {"theta": [9 numbers], ...}, ...},
     "names": ["theta1", ...], "units": [...], ...}

A hand-written file may be as small as ``{"theta": [9 numbers]}``. :func:`load_params` returns
the selected scheme's θ (or the one asked for) with the document, and fails with one line naming
the file and what is wrong.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drivers.recording import write_json_atomic
from hil.model.closed_form import TERMS, ArmModel

KIND = "ddbench parameters"

# The largest |θ| entry an arm can have, in θ's SI units (kg m², Nm, Nm s): the heaviest
# industrial arms (a tonne of payload at 3 m) have joint inertias near 2e4 kg m² and gravity
# torques near 1e5 Nm. A larger entry is a unit slip or a broken fit, and entries near float's
# range (±1e308) pass the M(q) test as inf > 0 but make a control law inf − inf = NaN.
MAX_THETA_MAGNITUDE = 1e6


class ParamsError(ValueError):
    """A parameter file that cannot be used; the message is one line naming the file."""


@dataclass(frozen=True)
class ParamSet:
    """θ1..θ9 and where they came from (a file and scheme, or a robot profile)."""

    theta: np.ndarray
    source: str
    scheme: str | None = None
    document: dict[str, Any] = field(default_factory=dict)
    terms: tuple[
        str, ...
    ] = ()  # hil.model.closed_form.ArmModel terms θ is written in (θ1..θ9 first)


def robot_params(robot: str = "cicese") -> ParamSet:
    """θ from a robot profile's Table I values (θ8 = mean of the two joint-1 directions)."""
    from profiles.robot import load_robot

    profile = load_robot(robot)
    return ParamSet(profile.theta(), source=profile.source, scheme="profile", terms=profile.terms)


def _terms_of(doc: dict[str, Any], where: str) -> tuple[str, ...]:
    terms = doc.get("model_terms", [])
    if not isinstance(terms, list) or any(t not in TERMS for t in terms):
        raise ParamsError(f"{where}: 'model_terms' must be a list of {', '.join(TERMS)}")
    return tuple(terms)


def _theta_of(entry: Any, where: str, terms: tuple[str, ...] = ()) -> np.ndarray:
    if not isinstance(entry, dict) or "theta" not in entry:
        raise ParamsError(f"{where}: no 'theta' list")
    theta = entry["theta"]
    names = ArmModel(terms).names
    if isinstance(theta, dict):
        missing = [n for n in names if n not in theta]
        if missing:
            raise ParamsError(f"{where}: 'theta' lacks {', '.join(missing)}")
        theta = [theta[n] for n in names]
    if not isinstance(theta, list) or len(theta) != len(names):
        raise ParamsError(f"{where}: 'theta' must be a list of {len(names)} numbers")
    if not all(isinstance(x, int | float) and not isinstance(x, bool) for x in theta):
        raise ParamsError(f"{where}: 'theta' must hold numbers only")
    if not all(math.isfinite(x) for x in theta):
        raise ParamsError(f"{where}: 'theta' holds a non-finite number")
    return np.array(theta, dtype=float)


def read_json_object(path: Path) -> dict:
    """The JSON object in ``path``; one-line :class:`ParamsError` if unreadable or not one."""
    try:
        doc = json.loads(path.read_text())
    except OSError as exc:
        raise ParamsError(f"{path}: cannot read ({exc.strerror})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ParamsError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise ParamsError(f"{path}: not a JSON object")
    return doc


def _identify_document(doc: dict[str, Any], where: str) -> dict[str, Any]:
    """A 2-DOF arm's ``identify.json`` (`hil identify`) read as a parameter file: the entries of
    its ``identifications`` (:meth:`hil.identify.identification.Identification.to_json`, one
    layout for every arm; in files older than it, the Table II layout's ``discretizations`` or
    the model-object layout's ``identification``) of the selected discretization as schemes,
    each with ``usable`` and ``failed_reason``, the ``selection``'s scheme selected. Any other
    document is returned as it is."""
    if doc.get("model") == "urdf":
        raise ParamsError(
            f"{where}: the identification of a URDF arm ({doc.get('robot')}): its base "
            "parameters are for that robot's model (--robot " + str(doc.get("robot")) + ")"
        )
    selection = doc.get("selection") if isinstance(doc.get("selection"), dict) else {}
    if isinstance(doc.get("identifications"), list):  # the layout of every arm
        disc = selection.get("discretization", "exact")
        entries = [
            e for e in doc["identifications"]
            if isinstance(e, dict) and e.get("discretization", "exact") == disc
        ]  # fmt: skip
        schemes = {e.get("scheme"): e for e in entries}
        terms = entries[0].get("terms", []) if entries else []
        return {
            **doc,
            "schemes": schemes,
            "selected": selection.get("scheme"),
            "model_terms": terms,
        }
    if isinstance(doc.get("discretizations"), dict):  # older files: the Table II layout
        disc = selection.get("discretization") or next(iter(doc["discretizations"]), None)
        entry = doc["discretizations"].get(disc)
        if not isinstance(entry, dict) or not isinstance(entry.get("schemes"), dict):
            raise ParamsError(f"{where}: no schemes of discretization {disc!r}")
        schemes = entry["schemes"]
    elif isinstance(doc.get("identification"), dict):  # older files: the model-object layout
        ident = doc["identification"]
        scheme = ident.get("scheme") or selection.get("scheme") or "filtered_dynamic"
        usable = {k: selection[k] for k in ("usable",) if k in selection}
        reason = {"failed_reason": selection["reason"]} if selection.get("reason") else {}
        schemes = {scheme: {**ident, **usable, **reason}}
        doc = {**doc, "model_terms": ident.get("model_terms", [])}
    else:
        return doc
    return {**doc, "schemes": schemes, "selected": selection.get("scheme")}


def load_params(path: str | Path, scheme: str | None = None) -> ParamSet:
    """Read a parameter file (``params.json``, or the ``identify.json`` of a 2-DOF arm, which
    holds the same θ: :func:`_identify_document`); ``scheme`` picks one of its schemes
    (default: its selected one)."""
    path = Path(path)
    doc = _identify_document(read_json_object(path), str(path))
    terms = _terms_of(doc, str(path))
    schemes = doc.get("schemes")
    if schemes is None:
        if scheme is not None:
            raise ParamsError(f"{path}: has no schemes, cannot select {scheme!r}")
        return ParamSet(_theta_of(doc, str(path), terms), str(path), doc.get("scheme"), doc, terms)
    if not isinstance(schemes, dict) or not schemes:
        raise ParamsError(f"{path}: 'schemes' must be a non-empty object")
    name = scheme or doc.get("selected") or next(iter(schemes))
    if name not in schemes:
        raise ParamsError(f"{path}: no scheme {name!r}; it has {', '.join(sorted(schemes))}")
    theta = _theta_of(schemes[name], f"{path}: scheme {name}", terms)
    _refuse_failed(schemes[name], f"{path}: scheme {name}")
    return ParamSet(theta, str(path), name, doc, terms)


def _refuse_failed(entry: dict, where: str) -> None:
    """One-line :class:`ParamsError` when `hil identify` marked the scheme's θ as no arm (its
    ``physical_consistency`` false, or ``usable`` false): a failed fit is never parameters."""
    consistency = entry.get("physical_consistency")
    if isinstance(consistency, dict) and consistency.get("consistent") is False:
        violations = consistency.get("violations")
        why = "; ".join(violations) if isinstance(violations, list) and violations else "FAILED"
        raise ParamsError(f"{where}: not physically consistent, a failed fit ({why})")
    if entry.get("usable") is False:
        raise ParamsError(f"{where}: FAILED, not parameters ({entry.get('failed_reason')})")


def check_inertia(params: ParamSet, model: Any = None) -> None:
    """One-line :class:`ParamsError` naming the file and the field unless θ describes an arm
    whose M(q) is positive definite for every q (``model.physical_consistency``; default the
    :class:`ArmModel` of ``params.terms``): θ all zero, a negative mass term or a failed fit
    would make every model-based law and simulation command or integrate nonsense, and so
    would an entry beyond :data:`MAX_THETA_MAGNITUDE`. Negative friction coefficients are let
    through (they only weaken a compensation)."""
    model = ArmModel(params.terms) if model is None else model
    where = f"{params.source}: 'theta'"
    if isinstance(params.document.get("schemes"), dict) and params.scheme is not None:
        where = f"{params.source}: scheme {params.scheme}: 'theta'"
    theta = np.asarray(params.theta, dtype=float)
    beyond = np.flatnonzero(~(np.abs(theta) <= MAX_THETA_MAGNITUDE))
    if beyond.size:
        i = int(beyond[0])
        name = model.names[i] if i < len(model.names) else f"theta[{i}]"
        raise ParamsError(
            f"{where}: {name} = {theta[i]:.4g} is beyond any arm's magnitude "
            f"(|θ| <= {MAX_THETA_MAGNITUDE:.0e} in kg m², Nm, Nm s)"
        )
    try:
        violations = model.physical_consistency(params.theta)["violations"]
    except ValueError as exc:  # θ of the wrong length for the model's terms
        raise ParamsError(f"{where}: {exc}") from None
    inertia = [v for v in violations if v.startswith("M(q)")]
    if inertia:
        raise ParamsError(f"{where}: not a physical arm: {inertia[0]}")


def save_params(
    path: str | Path,
    schemes: dict[str, dict[str, Any]],
    *,
    selected: str,
    robot: str,
    **meta: Any,
) -> Path:
    """Write a parameter file; each ``schemes[name]`` holds at least ``"theta"`` (9 numbers, or
    those of ``ArmModel(meta["model_terms"])``)."""
    if selected not in schemes:
        raise ValueError(f"selected scheme {selected!r} not among {sorted(schemes)}")
    doc = {
        "kind": KIND,
        "robot": robot,
        "selected": selected,
        "names": list(ArmModel(tuple(meta.get("model_terms", ()))).names),
        "units": list(ArmModel(tuple(meta.get("model_terms", ()))).units),
        **meta,
        "schemes": {
            name: {**entry, "theta": [float(x) for x in np.asarray(entry["theta"])]}
            for name, entry in schemes.items()
        },
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, doc)
    return path


def load_base_params(path: str | Path, model: Any) -> ParamSet:
    """A URDF arm's base parameters (:class:`hil.model.urdf.UrdfArmModel` ``model``) from the
    ``identify.json`` that `hil identify --robot R` writes for such an arm (its ``parameters``,
    each with ``name`` and ``identified``), or from ``{"theta": [p numbers]}``.

    The base parameters are combinations that depend on the URDF and the model terms, so an
    ``identify.json`` must be of the same robot and terms, with the same combination per name
    (``meaning``); one-line :class:`ParamsError` otherwise."""
    path = Path(path)
    doc = read_json_object(path)
    names, where = tuple(model.names), str(path)
    if "parameters" in doc:
        robot, terms = doc.get("robot"), doc.get("terms", [])
        if model.name and isinstance(robot, str) and Path(robot).stem != model.name:
            raise ParamsError(f"{where}: identified for robot {robot}, not {model.name}")
        if list(terms) != list(model.terms):
            raise ParamsError(
                f"{where}: model terms {terms}, robot {model.name} has {list(model.terms)}"
            )
        validation, selection = doc.get("validation"), doc.get("selection")
        if isinstance(validation, dict) and validation.get("passed") is False:
            raise ParamsError(
                f"{where}: its parameters ({doc.get('params_scheme')}) failed held-out "
                f"validation ({validation.get('reason')}); identify with a scheme that passed: "
                f"{', '.join(validation.get('schemes_passed') or []) or 'none did'}"
            )
        if isinstance(selection, dict) and selection.get("usable") is False:
            raise ParamsError(
                f"{where}: its parameters ({doc.get('params_scheme')}) FAILED "
                f"({selection.get('reason')}); usable schemes: "
                f"{', '.join(selection.get('schemes_usable') or []) or 'none'}"
            )
        entries = doc["parameters"]
        if not isinstance(entries, list) or [
            e.get("name") if isinstance(e, dict) else None for e in entries
        ] != list(names):
            raise ParamsError(f"{where}: 'parameters' must name {', '.join(names)} in order")
        for e, meaning in zip(entries, model.meanings, strict=True):
            if "meaning" in e and e["meaning"] != meaning:
                raise ParamsError(
                    f"{where}: {e['name']} is {e['meaning']!r} there, {meaning!r} for this arm"
                )
        # "estimate": every parameter's number; "identified" is None where the data did not
        # determine it (hil identify of a URDF arm), and the only number in older files
        theta = [e["estimate"] if "estimate" in e else e.get("identified") for e in entries]
        doc = {**doc, "theta": theta}
    wanted = len(names)
    theta = doc.get("theta")
    if not isinstance(theta, list) or len(theta) != wanted:
        raise ParamsError(f"{where}: 'theta' must be a list of {wanted} numbers ({names[0]}..)")
    if not all(isinstance(x, int | float) and not isinstance(x, bool) for x in theta):
        raise ParamsError(f"{where}: 'theta' must hold numbers only")
    if not all(math.isfinite(x) for x in theta):
        raise ParamsError(f"{where}: 'theta' holds a non-finite number")
    scheme = doc.get("method") if "parameters" in doc else doc.get("scheme")
    return ParamSet(np.array(theta, dtype=float), str(path), scheme, doc)


__all__ = [
    "KIND",
    "MAX_THETA_MAGNITUDE",
    "ParamSet",
    "ParamsError",
    "check_inertia",
    "load_base_params",
    "load_params",
    "robot_params",
    "save_params",
]
