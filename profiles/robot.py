"""Robot profiles: Table I physical parameters of a 2-DOF vertical arm and the θ they imply
(:class:`RobotProfile`), and arms described by a URDF plus what a URDF does not hold
(:class:`UrdfRobotProfile`: friction, rotor inertia, gear ratio, drives). Imports only
:mod:`profiles.loader`."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from profiles.loader import Fields, ProfileError, load_toml


@dataclass(frozen=True)
class Link:
    mass_kg: float
    com_m: float
    inertia_kgm2: float
    length_m: float | None = None


@dataclass(frozen=True)
class RobotProfile:
    """Physical parameters of the arm (Reyes & Kelly 1997, Table I) and its joint → drive map."""

    name: str
    source: str
    gravity_m_s2: float
    link1: Link
    link2: Link
    viscous_Nms: tuple[float, float]
    coulomb_positive_Nm: tuple[float, float]
    coulomb_negative_Nm: tuple[float, float]
    drives: tuple[str, str]
    urdf: str | None = None  # the same arm as a URDF (profiles/robots/*.urdf), for hil.urdf_model

    def theta(self) -> np.ndarray:
        """θ1..θ9 of Reyes & Kelly (1997) Section 5; θ8 is the mean of the two joint-1 directions.

        θ1 = m1 lc1² + m2 l1² + m2 lc2² + I1 + I2,  θ2 = l1 m2 lc2,  θ3 = m2 lc2² + I2,
        θ4 = g (lc1 m1 + m2 l1),  θ5 = g m2 lc2,  θ6 = b1,  θ7 = b2,  θ8 = fc1,  θ9 = fc2.
        """
        l1, m1, lc1, I1 = (
            self.link1.length_m,
            self.link1.mass_kg,
            self.link1.com_m,
            self.link1.inertia_kgm2,
        )
        m2, lc2, I2 = self.link2.mass_kg, self.link2.com_m, self.link2.inertia_kgm2
        g = self.gravity_m_s2
        assert l1 is not None
        fc = [
            (p + n) / 2
            for p, n in zip(self.coulomb_positive_Nm, self.coulomb_negative_Nm, strict=True)
        ]
        return np.array(
            [
                m1 * lc1**2 + m2 * l1**2 + m2 * lc2**2 + I1 + I2,
                l1 * m2 * lc2,
                m2 * lc2**2 + I2,
                g * (lc1 * m1 + m2 * l1),
                g * m2 * lc2,
                self.viscous_Nms[0],
                self.viscous_Nms[1],
                fc[0],
                fc[1],
            ]
        )


def _link(f: Fields, key: str, *, needs_length: bool) -> Link:
    t = f.table(key)
    t.only({"length_m", "mass_kg", "com_m", "inertia_kgm2"})
    return Link(
        mass_kg=t.number("mass_kg", positive=True),
        com_m=t.number("com_m", lo=0.0),
        inertia_kgm2=t.number("inertia_kgm2", lo=0.0),
        length_m=t.number("length_m", positive=True)
        if needs_length
        else (t.number("length_m", positive=True) if t.has("length_m") else None),
    )


def load_robot(name_or_path: str | Path) -> RobotProfile:
    data, source = load_toml("robots", name_or_path)
    f = Fields(data, source)
    if f.has("urdf") and not f.has("link1"):
        raise ProfileError(
            source,
            None,
            "an arm described by its URDF only: the 2-DOF closed-form model cannot use it "
            "(hil.urdf_model.UrdfArmModel can; see docs/urdf.md)",
        )
    f.only({"name", "description", "gravity_m_s2", "link1", "link2", "friction", "joints", "urdf"})
    fr = f.table("friction")
    fr.only({"viscous_Nms", "coulomb_positive_Nm", "coulomb_negative_Nm"})
    joints = f.table("joints")
    joints.only({"drives"})
    return RobotProfile(
        name=f.string("name"),
        source=source,
        gravity_m_s2=f.number("gravity_m_s2", positive=True),
        link1=_link(f, "link1", needs_length=True),
        link2=_link(f, "link2", needs_length=False),
        viscous_Nms=fr.numbers("viscous_Nms", 2, lo=0.0),
        coulomb_positive_Nm=fr.numbers("coulomb_positive_Nm", 2, lo=0.0),
        coulomb_negative_Nm=fr.numbers("coulomb_negative_Nm", 2, lo=0.0),
        drives=joints.strings("drives", 2),
        urdf=str(_urdf_path(f, source)) if f.has("urdf") else None,
    )


@dataclass(frozen=True)
class UrdfRobotProfile:
    """An n-joint arm: a URDF (rigid bodies and kinematics) plus, per joint, what a URDF does not
    hold: viscous and Coulomb friction, rotor inertia reflected to the joint (armature) and gear
    ratio, and the drive profile of each joint when there is one."""

    name: str
    source: str
    urdf: str  # absolute path of the URDF file
    gravity_m_s2: float
    n_joints: int
    viscous_Nms: tuple[float, ...]
    coulomb_positive_Nm: tuple[float, ...]
    coulomb_negative_Nm: tuple[float, ...]
    armature_kgm2: tuple[float, ...]
    gear_ratio: tuple[float, ...]
    drives: tuple[str, ...] | None
    terms: tuple[str, ...] = ()  # model terms beyond rigid bodies + friction (hil.urdf_model)

    @property
    def coulomb_Nm(self) -> tuple[float, ...]:
        """Symmetric Coulomb level per joint: the mean of the two directions."""
        return tuple(
            (p + n) / 2
            for p, n in zip(self.coulomb_positive_Nm, self.coulomb_negative_Nm, strict=True)
        )


def _urdf_path(f: Fields, source: str) -> Path:
    """The URDF a profile names: relative paths are relative to the profile's own folder."""
    path = Path(f.string("urdf"))
    if not path.is_absolute():
        path = Path(source).parent / path
    if not path.is_file():
        raise f.error("urdf", f"no such URDF file: {path}")
    return path.resolve()


def load_urdf_robot(name_or_path: str | Path) -> UrdfRobotProfile:
    """A robot profile with a ``urdf`` field, for :class:`hil.urdf_model.UrdfArmModel`.

    Fields: ``urdf`` (path, relative to the profile), ``gravity_m_s2``, ``[joints] count``,
    ``[friction] viscous_Nms / coulomb_positive_Nm / coulomb_negative_Nm`` (one number per joint),
    optional ``[joints] armature_kgm2`` (default 0), ``gear_ratio`` (default 1) and ``drives``,
    and ``terms`` (model terms, :data:`hil.urdf_model.TERMS`).
    The 2-DOF closed-form tables (``link1``, ``link2``) may sit beside them (cicese.toml) and are
    not read here.
    """
    data, source = load_toml("robots", name_or_path)
    f = Fields(data, source)
    f.only(
        {
            *("name", "description", "gravity_m_s2", "link1", "link2", "friction", "joints"),
            *("urdf", "terms"),
        }
    )
    if not f.has("urdf"):
        raise f.error("urdf", "missing: this robot profile names no URDF")
    urdf = str(_urdf_path(f, source))
    joints = f.table("joints")
    joints.only({"count", "drives", "armature_kgm2", "gear_ratio"})
    n = joints.integer("count", 2, lo=1) if f.has("link1") else joints.integer("count", lo=1)
    fr = f.table("friction")
    fr.only({"viscous_Nms", "coulomb_positive_Nm", "coulomb_negative_Nm"})
    return UrdfRobotProfile(
        name=f.string("name"),
        source=source,
        urdf=urdf,
        gravity_m_s2=f.number("gravity_m_s2", positive=True),
        n_joints=n,
        viscous_Nms=fr.numbers("viscous_Nms", n, lo=0.0),
        coulomb_positive_Nm=fr.numbers("coulomb_positive_Nm", n, lo=0.0),
        coulomb_negative_Nm=fr.numbers("coulomb_negative_Nm", n, lo=0.0),
        armature_kgm2=joints.numbers("armature_kgm2", n, [0.0] * n, lo=0.0),
        gear_ratio=joints.numbers("gear_ratio", n, [1.0] * n, positive=True),
        drives=joints.strings("drives", n) if joints.has("drives") else None,
        terms=_terms(f),
    )


def _terms(f: Fields) -> tuple[str, ...]:
    value = f.data.get("terms", [])
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise f.error("terms", "must be a list of model term names")
    return tuple(value)
