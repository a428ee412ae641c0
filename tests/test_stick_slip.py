"""The virtual robot's one stick–slip step (virtual_robot/stick_slip.py) and its two backends,
the 2-DOF closed-form plant and the n-joint Pinocchio plant (issue 29, item 5): the recordings
of a few golden cases (tests/golden_plant.py) byte for byte against their digests from before
the step was shared; Brent's method as scipy's brentq runs it; both plants through the one
step, its breakaway rule and its stick search."""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest
from golden_plant import cases, resolve
from scipy.optimize import brentq

from profiles.experiment import load_experiment
from profiles.robot import load_robot, load_urdf_robot
from virtual_robot import plant as plant_module
from virtual_robot import stick_slip
from virtual_robot import urdf_plant as urdf_plant_module
from virtual_robot.cli import main as vr_main
from virtual_robot.compiled_step import KERNEL_ENV
from virtual_robot.plant import Plant, PlantParams
from virtual_robot.stick_slip import breakaway_joint, brent_zero
from virtual_robot.urdf_plant import UrdfPlant, UrdfPlantParams

# signals.csv of golden cases, run on the tree before the plants shared their step
# (python tests/golden_plant.py --write DIR on 9b824b7; DIR/golden.json)
GOLDEN = {
    "sim-cicese-stribeck": "384e45dbb996c9eb6cb74b49d22220da069187f82b55eadd3e0f20b5f7331ab2",
    "sim-cicese-amplifier-lag": "92a014020da2cb6d1df5831fd3b465b5a20a5b6b7f62837513c8342e431c7b4d",
    # joints that break away on the lag's mean torque and stick again at once (s = 0)
    "sim-cicese-lag-symmetric": "34f30f6ce9a521304b3f224df72769f80aab2ca750cf1e7209910fde2039a73b",
    "sim-cicese3-stribeck-python": (
        "589ebe22d4bfd0a3fa2f0be3a8d326815aae0c8e5e9234477a34f51c4fb94177"
    ),
    "sim-cicese3-amplifier-lag-python": (
        "783ed790e1f3dacde0baebe1a7ce4181850a47431c4d530f550a40a3376a67c9"
    ),
    "sim-cicese3-none-compiled": "6fb4120d8919089fa74e70d938f403e97f616088e2907270cacabfc88a61f47a",
}


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_recording_is_byte_identical_to_the_golden_one(name, tmp_path, monkeypatch):
    """virtual-robot simulate of a golden case writes the signals.csv it wrote before the
    2-DOF and the n-joint plant shared one stick-slip step (stick events on every case)."""
    (case,) = [c for c in cases() if c[0] == name]
    _, command, args, env = case
    assert command == "virtual-robot simulate"
    monkeypatch.delenv(KERNEL_ENV, raising=False)
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    out = tmp_path / "run"
    assert vr_main(["simulate", *resolve(args, tmp_path), "--out", str(out), "--no-plot"]) == 0
    digest = hashlib.sha256((out / "signals.csv").read_bytes()).hexdigest()
    assert digest == GOLDEN[name]


def test_brent_zero_is_scipys_brentq():
    """Brent's method of the stick search gives scipy's brentq's root to the last bit (the same
    iterates: the n-joint plant's stick instants, and the compiled kernel's, are brentq's),
    on smooth functions, roots near an end, flat stretches and a root at an end."""
    rng = np.random.default_rng(29)
    functions = [
        (lambda x: x**3 - 2.0 * x - 5.0, 2.0, 3.0),
        (lambda x: math.cos(x) - x, 0.0, 1.0),
        (lambda x: math.exp(x) - 1e-9, -30.0, 1.0),
        (lambda x: math.tanh(50.0 * (x - 0.3)), 0.0, 1.0),
        (lambda x: (x - 1e-13) * 1e6, 0.0, 5e-4),
        (lambda x: x * x - 0.25, 0.5, 2.0),  # the root at an end
    ]
    for _ in range(40):
        c, k = rng.uniform(0.01, 0.99), rng.uniform(0.5, 40.0)
        functions.append((lambda x, c=c, k=k: math.sin(k * (x - c)) / k, c - 0.05, c + 0.07))
    for f, a, b in functions:
        for xtol in (1e-12, 1e-15 * (b - a), 1e-6):
            got = brent_zero(f, a, b, xtol)
            want = brentq(f, a, b, xtol=xtol, rtol=4 * np.finfo(float).eps)
            assert got == want or (math.isnan(got) and math.isnan(want))
    with pytest.raises(ValueError, match="different signs"):
        brent_zero(lambda x: x * x + 1.0, -1.0, 1.0, 1e-12)
    with pytest.raises(ValueError, match="NaN"):
        brent_zero(lambda x: math.nan if x > 0.2 else x - 0.5, 0.0, 1.0, 1e-12)


def test_breakaway_rule():
    """Karnopp's test: a holding torque strictly outside its band breaks the joint away, the
    one furthest outside relative to its band first; a joint on the band's edge stays."""
    bands = ((2.0, 1.0, 0.0), (1.0, 3.0, 0.0))
    stuck = (True, True, True)
    assert breakaway_joint((2.0, -3.0, 0.0), stuck, *bands) == -1  # on the edges
    assert breakaway_joint((2.2, -3.0, 0.0), stuck, *bands) == 0
    assert breakaway_joint((2.2, -3.6, 0.0), stuck, *bands) == 1  # 1.2 beats 1.1
    assert breakaway_joint((2.2, -3.6, 1e-9), stuck, *bands) == 2  # a zero band: any torque
    assert breakaway_joint((2.2, -3.6, 1e-9), (False, False, True), *bands) == 2
    assert breakaway_joint((5.0, 0.0, 0.0), (False, True, True), *bands) == -1


def _run(plant, torques, h):
    for k, tau in enumerate(torques):
        plant.command(tau)
        plant.advance_to((k + 1) * h)


@pytest.mark.parametrize("arm", ["closed form", "pinocchio"])
def test_both_plants_step_through_the_one_step(arm, monkeypatch):
    """The 2-DOF plant and the n-joint plant (its Python step) locate their stick events,
    release their stuck joints and take the steps with events through virtual_robot.stick_slip:
    its functions are called, and replacing its search's root finder by a wrong one changes
    the stick instants of both."""
    monkeypatch.setenv(KERNEL_ENV, "python")
    experiment = load_experiment("reyes-kelly")
    h = experiment.period_s
    torques = experiment.torque_rows(h, 400)

    def make():
        if arm == "closed form":
            return Plant(PlantParams.from_profiles(load_robot("cicese")))
        return UrdfPlant(UrdfPlantParams.from_profile(load_urdf_robot("cicese")))

    calls = {"step": 0, "locate_stick": 0, "release_stuck_joints": 0}
    for name in calls:
        real = getattr(stick_slip, name)

        def counted(*args, _real=real, _name=name, **kw):
            calls[_name] += 1
            return _real(*args, **kw)

        monkeypatch.setattr(stick_slip, name, counted)
        imported = "stick_slip_step" if name == "step" else name  # as the plants import it
        for module in (plant_module, urdf_plant_module):
            if hasattr(module, imported):
                monkeypatch.setattr(module, imported, counted)
    plant = make()
    _run(plant, torques, h)
    assert plant.stick_events > 0
    assert calls["step"] > 0 and calls["locate_stick"] == plant.stick_events
    assert calls["release_stuck_joints"] > 0
    state = (tuple(plant.q), tuple(plant.dq))

    # the search's bisection instead of Brent's method: other stick instants, other states
    def bisect(f, a, b, xtol, *_):
        fa = f(a)
        while b - a > xtol:
            m = 0.5 * (a + b)
            if (f(m) > 0) == (fa > 0):
                a = m
            else:
                b = m
        return b

    monkeypatch.setattr(stick_slip, "brent_zero", bisect)
    other = make()
    _run(other, torques, h)
    assert (tuple(other.q), tuple(other.dq)) != state


def test_a_stuck_arm_breaks_away_where_the_rule_says():
    """Held by a torque inside joint 1's band the 2-DOF arm does not move at all; just outside
    it, it breaks away in the torque's direction (the one rule, both directions)."""
    params = PlantParams.from_profiles(load_robot("cicese"))
    band_pos, band_neg = params.breakaway_positive_Nm[0], params.breakaway_negative_Nm[0]
    for torque, moves in ((band_pos - 0.05, False), (band_pos + 0.1, True),
                          (-band_neg + 0.05, False), (-band_neg - 0.1, True)):  # fmt: skip
        plant = Plant(params)
        plant.command((torque, 0.0))
        plant.advance_to(0.2)
        assert (plant.q[0] != 0.0) == moves
        if moves:
            assert math.copysign(1.0, plant.q[0]) == math.copysign(1.0, torque)


class Block:
    """A third backend of the one step: a block of mass m on a table with Coulomb friction F
    (static band F both ways) under a held force, whose RK4 flow is exact (constant
    acceleration), so the step's events have closed forms."""

    n_joints = 1

    def __init__(self, mass: float, friction: float, x: float = 0.0, v: float = 0.0) -> None:
        self.m, self.friction, self.x, self.v, self.force = mass, friction, x, v, 0.0
        self.t, self.steps, self.stick_events, self.dissipated = 0.0, 0, 0, 0.0
        self.stuck = [v == 0.0]
        self.slip_dir = [1.0 if v >= 0 else -1.0]
        self.band_positive = self.band_negative = (friction,)

    def any_stuck(self) -> bool:
        return self.stuck[0]

    def hold_torque(self, dt: float) -> None:
        pass

    def flow(self, s: float) -> tuple[float, float]:
        a = 0.0 if self.stuck[0] else (self.force - self.slip_dir[0] * self.friction) / self.m
        return self.x + self.v * s + 0.5 * a * s * s, self.v + a * s

    def start(self) -> tuple[float, float]:
        return self.x, self.v

    def velocity(self, end, joint: int) -> float:
        return end[1]

    def crossed(self, end) -> list[int]:
        return [0] if not self.stuck[0] and end[1] * self.slip_dir[0] < 0.0 else []

    def locate(self, dt, crossed, end):
        return stick_slip.locate_stick(self, dt, crossed, end)

    def commit(self, end, s: float) -> None:
        self.x, self.v = end

    def holding_torques(self) -> list[float]:
        return [self.force if self.stuck[0] else 0.0]

    def energy_J(self) -> float:
        return 0.5 * self.m * self.v * self.v

    def rest(self, joint: int) -> None:
        self.v = 0.0

    def dissipate(self, energy_J: float) -> None:
        self.dissipated += energy_J

    def mode_changed(self) -> None:
        pass


def test_the_step_on_a_block_with_coulomb_friction():
    """Any arm that gives the interface takes the step: a sliding block stops where
    v0 − (F/m) t = 0 and sticks (located to ~1e-12 of the step), stays stuck under a force
    inside its band, breaks away in the force's direction outside it; a joint already moving
    against its slip direction sticks at once."""
    block = Block(mass=2.0, friction=4.0, v=1.0)
    stick_slip.step(block, 1.0)
    assert block.t == 1.0 and block.stuck == [True] and block.v == 0.0
    assert block.stick_events == 1 and block.steps == 2  # cut at the stop, then the rest
    assert block.x == pytest.approx(0.25, abs=1e-12)  # v0 t* − F t*²/(2m), t* = m v0 / F
    block.force = -3.9  # inside the band: not a hair of motion
    stick_slip.step(block, 0.5)
    assert block.stuck == [True] and block.x == pytest.approx(0.25, abs=1e-12)
    block.force = -5.0  # outside: slides backwards at (F_applied + F) / m
    x0 = block.x
    stick_slip.step(block, 0.5)
    assert block.stuck == [False] and block.slip_dir == [-1.0]
    assert block.v == pytest.approx(-0.25) and block.x == pytest.approx(x0 - 0.0625)
    against = Block(mass=1.0, friction=1.0, v=-0.1)
    against.slip_dir = [1.0]  # moving against its slip direction at the step start
    s, joint, end = stick_slip.locate_stick(against, 0.01, [0], against.flow(0.01))
    assert (s, joint, end) == (0.0, 0, (0.0, -0.1))
