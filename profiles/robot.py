"""Robot profile: physical parameters of a 2-DOF vertical arm, the model terms it has, and the
θ they imply.

A profile gives each link's mass, centre of mass (along the link, ``com_m``, and across it,
``com_across_m``, default 0) and inertia (about its centre of mass, ``inertia_kgm2``, as in
Reyes & Kelly (1997) Table I, or about its joint axis, ``inertia_about_joint_kgm2``, as the DFKI
owners publish it); optionally the motors' rotors (``[rotor]``: inertia, gear ratio, and the
sign with which motor 2's rotor turns relative to link 1); friction as Coulomb levels or as the
smooth ``cf · atan(k q̇)`` law (level cf·π/2); and ``[model] terms`` (of
:data:`TERMS`) the arm has. :meth:`RobotProfile.theta` gives θ in the parametrisation of
``hil.model.closed_form.ArmModel(profile.terms)`` (θ1..θ9, then each term's parameters).

Arms of any number of joints are described by a URDF plus what a URDF does not hold
(:class:`UrdfRobotProfile`, :func:`load_urdf_robot`, for :mod:`hil.model.urdf`): friction per
joint, rotor inertia (armature), gear ratio, drives. A 2-DOF profile may name the same arm's
URDF (``urdf``, cicese.toml)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from profiles.limits import JointLimits, parse_limits
from profiles.loader import Fields, ProfileError, load_toml

# The closed-form model's optional terms a profile may name under ``[model] terms``
# (hil.model.closed_form builds them: ArmModel(profile.terms)); the profile is the vocabulary so
# that this bottom layer imports nothing from hil.
TERMS = ("rotor_inertia", "com_offset")


@dataclass(frozen=True)
class Link:
    mass_kg: float
    com_m: float
    inertia_kgm2: float  # about the centre of mass
    length_m: float | None = None
    com_across_m: float = 0.0  # centre of mass across the link, towards increasing q

    def inertia_about_joint(self) -> float:
        """I about the joint axis (parallel-axis theorem)."""
        return self.inertia_kgm2 + self.mass_kg * (self.com_m**2 + self.com_across_m**2)


@dataclass(frozen=True)
class Rotor:
    """The motors' rotors: same inertia and gear ratio on both joints (a quasi-direct drive).
    Motor 1's rotor turns by gr·q1 on the base; motor 2's, on link 1, by q1 + coupling·gr·q2."""

    inertia_kgm2: float
    gear_ratio: float
    coupling: float  # +1 or −1
    datasheet_inertia_kgm2: float | None = None

    def inertia_from_theta(self, theta_rotor: float) -> float:
        """Ir from θ_rotor = gr² Ir − coupling·gr·Ir (hil.model.closed_form)."""
        return theta_rotor / (self.gear_ratio**2 - self.coupling * self.gear_ratio)


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
    drives: tuple[str, ...]
    terms: tuple[str, ...] = ()
    rotor: Rotor | None = None
    reference: str = ""
    urdf: str | None = None  # the same arm as a URDF (profiles/robots/*.urdf), for hil.model.urdf

    @property
    def n_joints(self) -> int:
        return 2  # the closed-form model's two links

    def theta(self) -> np.ndarray:
        """θ of :meth:`model`: θ1..θ9 of Reyes & Kelly (1997) Section 5 (θ8, θ9 the mean of the
        two directions), then each term's parameters (hil.model.closed_form):

        θ1 = m1 lc1² + m2 l1² + m2 lc2² + I1 + I2 [+ (gr² + 1) Ir],  θ2 = l1 m2 lc2,
        θ3 = m2 lc2² + I2 [+ coupling·gr·Ir],  θ4 = g (lc1 m1 + m2 l1),  θ5 = g m2 lc2,
        θ6 = b1,  θ7 = b2,  θ8 = fc1,  θ9 = fc2;
        θ_rotor = gr² Ir − coupling·gr·Ir;  θ2⊥ = l1 m2 ly2,  θ4⊥ = g m1 ly1,  θ5⊥ = g m2 ly2
        (I about the centre of mass, with ly: I about the joint is I + m (lc² + ly²)).
        """
        base = self._theta9()
        extra: list[float] = []
        for term in self.terms:
            if term == "rotor_inertia":
                r = self.rotor
                assert r is not None
                extra.append(
                    r.gear_ratio**2 * r.inertia_kgm2 - r.coupling * r.gear_ratio * r.inertia_kgm2
                )
            elif term == "com_offset":
                g, l1 = self.gravity_m_s2, self.link1.length_m
                assert l1 is not None
                extra += [
                    l1 * self.link2.mass_kg * self.link2.com_across_m,
                    g * self.link1.mass_kg * self.link1.com_across_m,
                    g * self.link2.mass_kg * self.link2.com_across_m,
                ]
        return np.concatenate([base, extra]) if extra else base

    def _theta9(self) -> np.ndarray:
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
        if self.link1.com_across_m or self.link2.com_across_m:
            I1 += m1 * self.link1.com_across_m**2  # the across part of the parallel axis
            I2 += m2 * self.link2.com_across_m**2
        theta1 = m1 * lc1**2 + m2 * l1**2 + m2 * lc2**2 + I1 + I2
        theta3 = m2 * lc2**2 + I2
        if (
            self.rotor is not None
        ):  # hil.model.closed_form: K_r = ½ Ir (gr q̇1)² + ½ Ir (q̇1 + c gr q̇2)²
            r = self.rotor
            theta1 += (r.gear_ratio**2 + 1) * r.inertia_kgm2
            theta3 += r.coupling * r.gear_ratio * r.inertia_kgm2
        return np.array(
            [
                theta1,
                l1 * m2 * lc2,
                theta3,
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
    t.only(
        {"length_m", "mass_kg", "com_m", "com_across_m", "inertia_kgm2", "inertia_about_joint_kgm2"}
    )
    mass = t.number("mass_kg", positive=True)
    com = t.number("com_m", lo=0.0)
    across = t.number("com_across_m", 0.0)
    if t.has("inertia_kgm2") == t.has("inertia_about_joint_kgm2"):
        raise t.error("inertia_kgm2", "give exactly one of inertia_kgm2, inertia_about_joint_kgm2")
    if t.has("inertia_kgm2"):
        inertia = t.number("inertia_kgm2", lo=0.0)
    else:
        about_joint = t.number("inertia_about_joint_kgm2", positive=True)
        inertia = about_joint - mass * (com**2 + across**2)
        if inertia < 0:
            raise t.error(
                "inertia_about_joint_kgm2",
                f"{about_joint:g} kg m² is less than m (lc² + ly²) = {about_joint - inertia:g}: "
                "not a physical link",
            )
    return Link(
        mass_kg=mass,
        com_m=com,
        inertia_kgm2=inertia,
        length_m=t.number("length_m", positive=True)
        if needs_length
        else (t.number("length_m", positive=True) if t.has("length_m") else None),
        com_across_m=across,
    )


def _coulomb(fr: Fields) -> tuple[tuple[float, float], tuple[float, float]]:
    """Coulomb levels (positive, negative direction). ``coulomb_atan_Nm`` = cf of the smooth law
    cf · atan(k q̇) (the DFKI owners' model) maps to the level cf · π/2 it tends to once
    |q̇| ≫ 1/k (k = 100 s/rad there: above 0.1 rad/s it is within 6 % of it)."""
    if fr.has("coulomb_atan_Nm"):
        if fr.has("coulomb_positive_Nm") or fr.has("coulomb_negative_Nm"):
            raise fr.error("coulomb_atan_Nm", "give Coulomb levels or coulomb_atan_Nm, not both")
        cf = fr.numbers("coulomb_atan_Nm", 2, lo=0.0)
        level = (cf[0] * math.pi / 2, cf[1] * math.pi / 2)
        return level, level
    return (
        fr.numbers("coulomb_positive_Nm", 2, lo=0.0),
        fr.numbers("coulomb_negative_Nm", 2, lo=0.0),
    )


def load_robot(name_or_path: str | Path) -> RobotProfile:
    data, source = load_toml("robots", name_or_path)
    f = Fields(data, source)
    if f.has("urdf") and not f.has("link1"):
        raise ProfileError(
            source,
            None,
            "an arm described by its URDF only: the 2-DOF closed-form model cannot use it "
            "(hil.model.urdf.UrdfArmModel can; see docs/urdf.md)",
        )
    f.only(
        {
            "name",
            "description",
            "reference",
            "gravity_m_s2",
            "link1",
            "link2",
            "rotor",
            "friction",
            "joints",
            "model",
            "urdf",
        }
    )
    fr = f.table("friction")
    fr.only({"viscous_Nms", "coulomb_positive_Nm", "coulomb_negative_Nm", "coulomb_atan_Nm"})
    positive, negative = _coulomb(fr)
    drives: tuple[str, ...] = ()
    if f.has("joints"):
        joints = f.table("joints")
        joints.only({"drives"})
        drives = joints.strings("drives", 2)
    terms: tuple[str, ...] = ()
    if f.has("model"):
        mt = f.table("model")
        mt.only({"terms"})
        raw = mt._get("terms", [])
        if not isinstance(raw, list) or not all(isinstance(x, str) for x in raw):
            raise mt.error("terms", "must be a list of strings")
        unknown = [x for x in raw if x not in TERMS]
        if unknown or len(set(raw)) != len(raw):
            raise mt.error("terms", f"must be distinct names from {', '.join(TERMS)}; got {raw}")
        terms = tuple(raw)
    rotor = None
    if f.has("rotor"):
        rt = f.table("rotor")
        rt.only({"inertia_kgm2", "gear_ratio", "coupling", "datasheet_inertia_kgm2"})
        coupling = rt.number("coupling")
        if coupling not in (1.0, -1.0):
            raise rt.error("coupling", f"must be +1 or -1, got {coupling:g}")
        rotor = Rotor(
            rt.number("inertia_kgm2", lo=0.0),
            rt.number("gear_ratio", positive=True),
            coupling,
            rt.number("datasheet_inertia_kgm2", positive=True)
            if rt.has("datasheet_inertia_kgm2")
            else None,
        )
        if "rotor_inertia" not in terms:
            raise f.error("rotor", "a [rotor] needs model.terms to include rotor_inertia")
    elif "rotor_inertia" in terms:
        raise f.error("model", "terms include rotor_inertia but there is no [rotor] table")
    link1 = _link(f, "link1", needs_length=True)
    link2 = _link(f, "link2", needs_length=False)
    if (link1.com_across_m or link2.com_across_m) and "com_offset" not in terms:
        raise f.error("model", "a link has com_across_m but terms lack com_offset")
    return RobotProfile(
        name=f.string("name"),
        source=source,
        gravity_m_s2=f.number("gravity_m_s2", positive=True),
        link1=link1,
        link2=link2,
        viscous_Nms=fr.numbers("viscous_Nms", 2, lo=0.0),
        coulomb_positive_Nm=positive,
        coulomb_negative_Nm=negative,
        drives=drives,
        terms=terms,
        rotor=rotor,
        reference=f.string("reference", ""),
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
    terms: tuple[str, ...] = ()  # model terms beyond rigid bodies + friction (hil.model.urdf)
    # host limits of this arm on a bench whose own [limits] are another robot's (bench_for_robot)
    limits: JointLimits | None = None

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
    """A robot profile with a ``urdf`` field, for :class:`hil.model.urdf.UrdfArmModel`.

    Fields: ``urdf`` (path, relative to the profile), ``gravity_m_s2``, ``[joints] count``,
    ``[friction] viscous_Nms / coulomb_positive_Nm / coulomb_negative_Nm`` (one number per joint),
    optional ``[joints] armature_kgm2`` (default 0), ``gear_ratio`` (default 1) and ``drives``,
    ``[model] terms`` (:data:`hil.model.urdf.TERMS`) and ``[limits]`` (host limits per joint,
    :mod:`profiles.limits`).
    The 2-DOF closed-form tables (``link1``, ``link2``) may sit beside them (cicese.toml) and are
    not read here.
    """
    data, source = load_toml("robots", name_or_path)
    f = Fields(data, source)
    planar = f.has("link1")
    if not planar:  # the 2-DOF tables of a planar profile are checked by load_robot
        f.only(
            {"name", "description", "reference", "gravity_m_s2", "friction", "joints"}
            | {"urdf", "model", "limits"}
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
        limits=parse_limits(f.table("limits"), n) if f.has("limits") and not planar else None,
    )


def _terms(f: Fields) -> tuple[str, ...]:
    """``[model] terms`` of a URDF-only profile (hil.model.urdf.TERMS). A planar profile's
    ``[model] terms`` name closed-form terms (hil.model.closed_form.TERMS) and are not read here:
    its URDF
    already holds what they add (centres of mass off the link line)."""
    if f.has("link1") or not f.has("model"):
        return ()
    mt = f.table("model")
    mt.only({"terms"})
    value = mt.data.get("terms", [])
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise mt.error("terms", "must be a list of model term names")
    return tuple(value)


def describes_urdf_only(name_or_path: str | Path) -> bool:
    """The robot profile describes its arm by a URDF only (no 2-DOF closed-form tables)."""
    data, _ = load_toml("robots", name_or_path)
    return "urdf" in data and "link1" not in data


def load_any_robot(name_or_path: str | Path) -> RobotProfile | UrdfRobotProfile:
    """The 2-DOF closed-form profile (:func:`load_robot`), or, for an arm described by its URDF
    only, the n-joint profile (:func:`load_urdf_robot`)."""
    if describes_urdf_only(name_or_path):
        return load_urdf_robot(name_or_path)
    return load_robot(name_or_path)


__all__ = [
    "TERMS",
    "Link",
    "RobotProfile",
    "Rotor",
    "UrdfRobotProfile",
    "describes_urdf_only",
    "load_any_robot",
    "load_robot",
    "load_urdf_robot",
]
