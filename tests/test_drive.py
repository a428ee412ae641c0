"""Tests for the emulated CiA 402 servo drive (virtual_robot.drive)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.units import counts_to_rad, position_to_rad
from profiles.drive import load_drive
from virtual_robot.drive import (
    ABORT_VALUE_RANGE,
    ABORT_VALUE_TOO_HIGH,
    ABORT_VALUE_TOO_LOW,
    ERR_NONE,
    ERR_OVERSPEED,
    ERR_RPDO_TIMEOUT,
    INT32_MAX,
    INT32_MIN,
    MODE_CST,
    MODE_TQ,
    DriveError,
    DriveModel,
    Emcy,
    State,
    state_from_statusword,
)

DM1200A = load_drive("dm1200a")
DM1015B = load_drive("dm1015b")
DT = 0.001


def enabled(profile=DM1200A) -> DriveModel:
    d = DriveModel(profile)
    for cw in (0x06, 0x07, 0x0F):
        d.write_controlword(cw, 0.0)
    assert d.state is State.OPERATION_ENABLED
    return d


def check_sw(d: DriveModel, state: State) -> None:
    assert d.state is state
    assert state_from_statusword(d.statusword) is state
    assert d.statusword & 0x0200  # remote


# ----------------------------------------------------------------- state machine


def test_boot_and_enable_sequence() -> None:
    d = DriveModel(DM1200A, boot_time_s=1.0)
    check_sw(d, State.NOT_READY_TO_SWITCH_ON)
    assert d.statusword & 0x4F == 0x00
    d.write_controlword(0x06, 0.5)  # before boot: ignored
    check_sw(d, State.NOT_READY_TO_SWITCH_ON)
    assert d.controlword == 0
    d.update(1.0, 0.0, 0.0)  # transition 1
    check_sw(d, State.SWITCH_ON_DISABLED)
    assert d.statusword & 0x4F == 0x40
    d.write_controlword(0x06, 1.0)
    check_sw(d, State.READY_TO_SWITCH_ON)
    assert d.statusword & 0x6F == 0x21
    d.write_controlword(0x07, 1.0)
    check_sw(d, State.SWITCHED_ON)
    assert d.statusword & 0x6F == 0x23
    d.write_controlword(0x0F, 1.0)
    check_sw(d, State.OPERATION_ENABLED)
    assert d.statusword & 0x6F == 0x27
    assert d.statusword & 0x0400  # target reached
    assert d.controlword == 0x0F


def test_boot_on_first_write_at_boot_time() -> None:
    d = DriveModel(DM1200A, boot_time_s=2.0)
    d.write_controlword(0x06, 2.0)  # boots, then shutdown applies
    check_sw(d, State.READY_TO_SWITCH_ON)


def test_enable_directly_from_ready() -> None:
    d = DriveModel(DM1200A)
    d.write_controlword(0x06, 0.0)
    d.write_controlword(0x0F, 0.0)
    check_sw(d, State.OPERATION_ENABLED)


def test_invalid_commands_ignored() -> None:
    d = DriveModel(DM1200A)
    d.write_controlword(0x0F, 0.0)  # enable from SWITCH_ON_DISABLED: not valid
    check_sw(d, State.SWITCH_ON_DISABLED)
    d.write_controlword(0x07, 0.0)
    check_sw(d, State.SWITCH_ON_DISABLED)


@pytest.mark.parametrize(
    ("cw", "state"),
    [
        (0x07, State.SWITCHED_ON),  # 5 disable operation
        (0x06, State.READY_TO_SWITCH_ON),  # 8 shutdown
        (0x00, State.SWITCH_ON_DISABLED),  # 9 disable voltage
        (0x0D, State.SWITCH_ON_DISABLED),  # 9 disable voltage (bit 1 clear)
        (0x02, State.QUICK_STOP_ACTIVE),  # 11 quick stop
    ],
)
def test_leave_operation_enabled(cw: int, state: State) -> None:
    d = enabled()
    d.write_target_torque(500, 0.0)
    d.write_controlword(cw, 0.0)
    check_sw(d, state)
    assert d.torque_Nm == 0.0
    assert d.torque_actual_permille == 0


def test_quick_stop_and_reenable() -> None:
    d = enabled()
    d.write_target_torque(300, 0.0)
    d.write_controlword(0x02, 0.0)
    check_sw(d, State.QUICK_STOP_ACTIVE)
    assert not d.statusword & 0x20  # bit 5 = 0: quick stop active
    for cw in (0x06, 0x07):  # stays in quick stop
        d.write_controlword(cw, 0.0)
        check_sw(d, State.QUICK_STOP_ACTIVE)
    for k in range(10):  # no watchdog in quick stop
        d.update(k * DT, 0.0, 0.0)
    check_sw(d, State.QUICK_STOP_ACTIVE)
    assert d.torque_Nm == 0.0
    d.write_controlword(0x0F, 0.0)  # 16
    check_sw(d, State.OPERATION_ENABLED)
    assert d.torque_Nm == pytest.approx(60.0)
    d.write_controlword(0x02, 0.0)
    d.write_controlword(0x00, 0.0)  # 12
    check_sw(d, State.SWITCH_ON_DISABLED)


def test_halt_bit_zeroes_torque() -> None:
    d = enabled()
    d.write_target_torque(500, 0.0)
    d.write_controlword(0x010F, 0.0)
    check_sw(d, State.OPERATION_ENABLED)
    assert d.torque_Nm == 0.0
    d.write_controlword(0x000F, 0.0)
    assert d.torque_Nm == pytest.approx(100.0)


def test_halt_target_reached_means_the_axis_has_stopped() -> None:
    """CiA 402 statusword bit 10 with halt (controlword bit 8) set: 0 while the axis
    decelerates, 1 once its velocity is 0; the torque is 0 throughout."""
    d = enabled()
    rpc = DM1200A.rad_per_count
    d.write_target_torque(500, 0.0)
    d.update(0.0, 0.0, 0.0)
    assert d.statusword & 0x0400  # not halted: the torque target is applied
    d.write_controlword(0x010F, 0.0)
    for k, counts in enumerate((3, 5, 6), start=1):  # halted, still coasting
        d.update(k * DT, (counts + 0.5) * rpc, 1.0)
        assert d.velocity_counts_s != 0
        assert d.torque_Nm == 0.0
        assert d.statusword == 0x0237, k  # enabled, bit 10 clear
    d.update(4 * DT, 6.5 * rpc, 0.0)  # no count in the last period: stopped
    assert d.velocity_counts_s == 0
    assert d.statusword == 0x0637
    d.update(5 * DT, 7.5 * rpc, 1.0)  # pushed again: moving, not reached
    assert not d.statusword & 0x0400
    d.write_controlword(0x000F, 5 * DT)  # halt released: bit 10 follows the torque target
    assert d.statusword & 0x0400


# ----------------------------------------------------------------- torque


def test_torque_scaling() -> None:
    d = enabled()
    d.write_target_torque(500, 0.0)
    assert d.torque_actual_permille == 500
    assert d.torque_Nm == pytest.approx(100.0)
    d.write_target_torque(-1, 0.0)
    assert d.torque_Nm == pytest.approx(-0.2)
    e = enabled(DM1015B)
    e.write_target_torque(1, 0.0)
    assert e.torque_Nm == pytest.approx(0.015)


def test_torque_clamp_sets_internal_limit_bit() -> None:
    """A clamped target shows on the bus: statusword bit 11 set, bit 10 (reached) clear."""
    d = enabled()
    d.write_target_torque(1500, 0.0)
    assert d.torque_actual_permille == 1000
    assert d.torque_Nm == pytest.approx(200.0)
    assert d.statusword & 0x0800
    assert not d.statusword & 0x0400
    d.write_max_torque(250)
    d.write_target_torque(-300, 0.0)
    assert d.torque_actual_permille == -250
    assert d.statusword & 0x0800
    d.write_target_torque(200, 0.0)
    assert not d.statusword & 0x0800
    assert d.statusword & 0x0400


def test_torque_zero_when_not_enabled() -> None:
    d = DriveModel(DM1200A)
    d.write_target_torque(500, 0.0)
    for cw in (0x06, 0x07):
        d.write_controlword(cw, 0.0)
        assert d.torque_Nm == 0.0
        assert d.torque_actual_permille == 0
        assert not d.statusword & 0x0800
    assert d.target_torque_permille == 500


def test_range_errors() -> None:
    d = DriveModel(DM1200A)
    with pytest.raises(DriveError) as exc:
        d.write_target_torque(32768, 0.0)
    assert exc.value.abort_code == ABORT_VALUE_TOO_HIGH
    with pytest.raises(DriveError) as exc:
        d.write_target_torque(-32769, 0.0)
    assert exc.value.abort_code == ABORT_VALUE_TOO_LOW
    d.write_target_torque(-32768, 0.0)
    d.write_target_torque(32767, 0.0)
    for cw in (-1, 0x10000):
        with pytest.raises(DriveError) as exc:
            d.write_controlword(cw, 0.0)
        assert exc.value.abort_code == ABORT_VALUE_RANGE
    with pytest.raises(DriveError) as exc:
        d.write_max_torque(0)
    assert exc.value.abort_code == ABORT_VALUE_TOO_LOW
    with pytest.raises(DriveError) as exc:
        d.write_max_torque(32768)
    assert exc.value.abort_code == ABORT_VALUE_TOO_HIGH
    with pytest.raises(DriveError) as exc:
        d.write_mode(8)
    assert exc.value.abort_code == ABORT_VALUE_RANGE
    assert d.mode == MODE_CST
    d.write_mode(MODE_TQ)
    assert d.mode == MODE_TQ


# ----------------------------------------------------------------- watchdog and faults


def test_watchdog_boundary_and_fault_reset() -> None:
    n = DM1200A.watchdog_periods(0.0025)
    assert n >= 2
    d = enabled()
    d.write_target_torque(500, 0.0)
    for k in range(1, n):
        d.update(k * DT, 0.0, 0.0)
    check_sw(d, State.OPERATION_ENABLED)  # n - 1 updates without a write: still enabled
    assert d.torque_Nm == pytest.approx(100.0)
    assert d.pop_emcy() == []
    d.update(n * DT, 0.0, 0.0)  # n-th: fault
    check_sw(d, State.FAULT)
    assert d.torque_Nm == 0.0
    assert d.error_code == ERR_RPDO_TIMEOUT == 0x8250
    assert d.error_register == 0x11
    assert d.pop_emcy() == [Emcy(0x8250, 0x11, n * DT)]
    d.update((n + 1) * DT, 0.0, 0.0)
    d.write_controlword(0x0F, (n + 1) * DT)  # not a fault reset: ignored
    check_sw(d, State.FAULT)
    assert d.pop_emcy() == []

    d.write_controlword(0x80, 5 * DT)  # rising edge of bit 7: transition 15
    check_sw(d, State.SWITCH_ON_DISABLED)
    assert d.error_code == ERR_NONE
    assert d.error_register == 0
    assert d.pop_emcy() == [Emcy(0, 0, 5 * DT)]

    for cw in (0x06, 0x07, 0x0F):
        d.write_controlword(cw, 6 * DT)
    check_sw(d, State.OPERATION_ENABLED)
    assert d.torque_Nm == pytest.approx(100.0)  # target kept


def test_watchdog_fed_by_writes_and_reset_on_enable() -> None:
    n = DM1200A.watchdog_periods(0.0025)
    d = enabled()
    for k in range(50):
        d.write_target_torque(100, k * DT)
        for _ in range(n - 1):  # n - 1 periods between writes: never trips
            d.update(k * DT, 0.0, 0.0)
    check_sw(d, State.OPERATION_ENABLED)
    d.update(1.0, 0.0, 0.0)  # counter n: fault
    check_sw(d, State.FAULT)
    # Entering OPERATION_ENABLED resets the counter even without a torque write.
    d.write_controlword(0x80, 1.0)
    for cw in (0x06, 0x07):
        d.write_controlword(cw, 1.0)
    d.update(1.0, 0.0, 0.0)  # not enabled: not counted
    d.update(1.0, 0.0, 0.0)
    d.write_controlword(0x0F, 1.0)
    for _ in range(n - 1):
        d.update(1.0, 0.0, 0.0)
    check_sw(d, State.OPERATION_ENABLED)


def test_fault_reset_needs_rising_edge() -> None:
    d = enabled()
    d.write_controlword(0x8F, 0.0)  # bit 7 held high while enabled
    check_sw(d, State.OPERATION_ENABLED)
    for k in range(DM1200A.watchdog_periods(0.0025)):
        d.update(k * DT, 0.0, 0.0)
    check_sw(d, State.FAULT)
    d.write_controlword(0x80, 0.0)  # bit 7 was already high: no edge
    check_sw(d, State.FAULT)
    d.write_controlword(0x00, 0.0)
    d.write_controlword(0x80, 0.0)
    check_sw(d, State.SWITCH_ON_DISABLED)


def test_overspeed_fault() -> None:
    d = enabled(DM1015B)
    d.write_target_torque(100, 0.0)
    d.update(DT, 0.0, 25.0)  # at the threshold: fine
    check_sw(d, State.OPERATION_ENABLED)
    d.write_target_torque(100, DT)
    d.update(2 * DT, 0.0, -25.01)
    check_sw(d, State.FAULT)
    assert d.error_code == ERR_OVERSPEED
    assert d.error_register == 0x21
    assert d.torque_Nm == 0.0
    assert d.pop_emcy() == [Emcy(ERR_OVERSPEED, 0x21, 2 * DT)]
    d.update(3 * DT, 0.0, 100.0)  # already in FAULT: no new EMCY
    assert d.pop_emcy() == []


def test_overspeed_only_when_powered() -> None:
    d = DriveModel(DM1200A)
    d.update(0.0, 0.0, 1000.0)
    check_sw(d, State.SWITCH_ON_DISABLED)
    d = enabled()
    d.write_controlword(0x02, 0.0)
    d.update(0.0, 0.0, 1000.0)
    check_sw(d, State.FAULT)
    assert d.error_code == ERR_OVERSPEED


def test_nmt_reset() -> None:
    d = enabled()
    d.write_max_torque(10)
    for k in range(DM1200A.watchdog_periods(0.0025)):
        d.update(k * DT, 1.0, 0.0)
    assert d.state is State.FAULT
    counts = d.position_counts
    d.reset(1.0)
    check_sw(d, State.NOT_READY_TO_SWITCH_ON)
    assert d.error_code == 0 and d.error_register == 0
    assert d.max_torque_permille == DM1200A.max_torque_permille
    assert d.position_counts == counts
    d.write_controlword(0x06, 1.0)
    check_sw(d, State.READY_TO_SWITCH_ON)


# ----------------------------------------------------------------- encoder


@pytest.mark.parametrize("profile", [DM1200A, DM1015B])
def test_encoder_counts(profile) -> None:
    assert profile.counts_per_rev in (1_024_000, 655_360)
    d = DriveModel(profile)
    quarter = profile.counts_per_rev // 4
    d.update(0.0, (quarter + 0.5) * profile.rad_per_count, 0.0)
    assert d.position_counts == quarter
    assert d.velocity_counts_s == 0  # first update
    d.update(0.5, (-quarter + 0.5) * profile.rad_per_count, 0.0)
    assert d.position_counts == -quarter
    assert d.velocity_counts_s == -4 * quarter
    d.update(1.0, -0.5 * profile.rad_per_count, 0.0)  # negative angles floor
    assert d.position_counts == -1
    d.update(1.0, 0.5 * profile.rad_per_count, 0.0)  # now <= t_prev: velocity 0
    assert d.position_counts == 0
    assert d.velocity_counts_s == 0


@pytest.mark.parametrize("profile", [DM1200A, DM1015B])
def test_encoder_floors_and_the_host_reads_the_centre_of_the_count(profile) -> None:
    """The convention, both ends: the drive's count is the floor (an encoder counts edges), the
    host's angle of a count is the centre of its cell (drivers.units.position_to_rad). Over
    angles spread across many cells the reading is without bias and within ½ count; the lower
    edge of the cell (counts · 2π/cpr) would be ½ count low on average."""
    rpc = profile.rad_per_count
    d = DriveModel(profile)
    angles = np.linspace(-3.1, 3.1, 20_001)  # not commensurate with a count: every phase
    read, edge = [], []
    for k, angle in enumerate(angles):
        d.update(k * DT, float(angle), 0.0)
        read.append(position_to_rad(d.position_counts, profile.counts_per_rev))
        edge.append(counts_to_rad(d.position_counts, profile.counts_per_rev))
        assert d.position_counts == math.floor(angle / rpc)
    error = (np.array(read) - angles) / rpc  # in counts
    assert np.all(np.abs(error) <= 0.5 + 1e-6)
    assert abs(error.mean()) < 0.01
    assert (np.array(edge) - angles).mean() / rpc == pytest.approx(-0.5, abs=0.01)
    assert position_to_rad(0, profile.counts_per_rev) == 0.5 * rpc
    assert position_to_rad(-1, profile.counts_per_rev) == -0.5 * rpc  # symmetric about 0


def test_encoder_counts_full_turn() -> None:
    d = DriveModel(DM1200A)
    d.update(0.0, math.pi / 3, 0.0)  # 1,024,000 / 6 = 170666.67
    assert d.position_counts == 170666
    d.update(0.0, -math.pi / 3, 0.0)
    assert d.position_counts == -170667


def test_encoder_int32_wrap() -> None:
    p = DM1200A
    d = DriveModel(p)
    d.update(0.0, (2**31 - 10 + 0.5) * p.rad_per_count, 0.0)
    assert d.position_counts == 2**31 - 10
    d.update(DT, (2**31 + 10 + 0.5) * p.rad_per_count, 0.0)
    assert d.position_counts == -(2**31) + 10
    assert d.velocity_counts_s == 20_000
    d.update(2 * DT, (2**31 + 30 + 0.5) * p.rad_per_count, 0.0)
    assert d.velocity_counts_s == 20_000
    d.update(3 * DT, -(2**31 + 5 - 0.5) * p.rad_per_count, 0.0)
    assert d.position_counts == 2**31 - 5
    assert d.velocity_counts_s == INT32_MIN  # clamped


def test_update_rejects_non_finite() -> None:
    d = DriveModel(DM1200A)
    with pytest.raises(ValueError):
        d.update(0.0, math.nan, 0.0)
    with pytest.raises(ValueError):
        d.update(0.0, 0.0, math.inf)


def test_state_from_statusword_unknown() -> None:
    assert state_from_statusword(0x0001) is None
    assert state_from_statusword(0x0237) is State.OPERATION_ENABLED
    assert state_from_statusword(0x0217) is State.QUICK_STOP_ACTIVE


# ----------------------------------------------------------------- property-based

finite = st.floats(allow_nan=False, allow_infinity=False)
# The meaningful controlwords are drawn more often than arbitrary ones, and "enable" (the first
# 1-3 words of 0x06, 0x07, 0x0F) and "fault reset" (0x00, 0x80) steps are added, so that the
# runs actually reach every state.
controlwords = st.one_of(
    st.sampled_from([0x00, 0x02, 0x06, 0x07, 0x0F, 0x80, 0x10F, 0x8F, 0x86]),
    st.integers(0, 0xFFFF),
    st.integers(-5, 0x10005),
)
cw_action = st.tuples(st.just("cw"), controlwords)
torque_action = st.tuples(
    st.just("torque"),
    st.one_of(st.integers(-1200, 1200), st.integers(-40000, 40000), st.integers()),
)
update_action = st.tuples(
    st.just("update"),
    st.tuples(
        st.floats(0.0, 0.01),
        st.one_of(st.floats(-1e4, 1e4), finite),
        st.one_of(st.floats(-30.0, 30.0), finite),
    ),
)
actions = st.one_of(
    cw_action,
    cw_action,
    st.tuples(st.just("enable"), st.sampled_from([3, 3, 3, 2, 1])),
    st.tuples(st.just("cw-seq"), st.just((0x00, 0x80))),
    torque_action,
    torque_action,
    update_action,
    update_action,
    st.tuples(st.just("idle"), st.integers(1, 4)),  # periods with no command: the watchdog
    st.tuples(st.just("mode"), st.one_of(st.sampled_from([4, 10]), st.integers())),
    st.tuples(st.just("max"), st.one_of(st.integers(1, 1500), st.integers(-5, 40000))),
    st.tuples(st.just("reset"), st.just(None)),
)


@settings(max_examples=200, deadline=None)
@given(
    profile=st.sampled_from([DM1200A, DM1015B]),
    boot=st.sampled_from([0.0, 0.0, 0.005]),
    steps=st.lists(actions, max_size=60),
)
def test_invariants(profile, boot: float, steps: list) -> None:
    d = DriveModel(profile, boot_time_s=boot)
    now = 0.0
    for kind, arg in steps:
        try:
            if kind == "cw":
                d.write_controlword(arg, now)
            elif kind == "enable":
                for cw in (0x06, 0x07, 0x0F)[:arg]:
                    d.write_controlword(cw, now)
            elif kind == "cw-seq":
                for cw in arg:
                    d.write_controlword(cw, now)
            elif kind == "torque":
                d.write_target_torque(arg, now)
            elif kind == "mode":
                d.write_mode(arg)
            elif kind == "max":
                d.write_max_torque(arg)
            elif kind == "update":
                dt, pos, vel = arg
                now += dt
                d.update(now, pos, vel)
            elif kind == "idle":
                for _ in range(arg):
                    now += DT
                    d.update(now, 0.0, 0.0)
            else:
                d.reset(now)
        except DriveError as exc:
            assert exc.abort_code in (ABORT_VALUE_RANGE, ABORT_VALUE_TOO_HIGH, ABORT_VALUE_TOO_LOW)
        assert isinstance(d.state, State)
        assert state_from_statusword(d.statusword) is d.state
        assert d.state is not State.FAULT_REACTION_ACTIVE
        limit = profile.rated_torque_Nm * d.max_torque_permille / 1000.0
        assert abs(d.torque_Nm) <= limit + 1e-9
        if d.state is not State.OPERATION_ENABLED:
            assert d.torque_Nm == 0.0
            assert d.torque_actual_permille == 0
        assert INT32_MIN <= d.position_counts <= INT32_MAX
        assert INT32_MIN <= d.velocity_counts_s <= INT32_MAX
        assert 0 <= d.statusword <= 0xFFFF
        # bit 11 (internal limit) exactly when the applied torque is not the target: clamped
        applying = d.state is State.OPERATION_ENABLED and not d.controlword & 0x0100
        clamped = applying and d.torque_actual_permille != d.target_torque_permille
        assert bool(d.statusword & 0x0800) == clamped
        assert d.mode in (MODE_CST, MODE_TQ)
        for ev in d.pop_emcy():
            assert ev.error_code in (ERR_NONE, ERR_RPDO_TIMEOUT, ERR_OVERSPEED)
        if d.state is State.FAULT:
            assert d.error_code in (ERR_RPDO_TIMEOUT, ERR_OVERSPEED)
        else:
            assert d.error_code == ERR_NONE and d.error_register == 0


def test_encoder_counts_and_velocity_exact_where_the_float_quotient_overflows() -> None:
    """update() divides by plain float division, and falls back to the exact quotient
    (Fraction) where that overflows: a position of 1.7e308 rad is counted exactly (the floor of
    the exact quotient, wrapped to INT32) and the velocity from the huge count change clamps to
    INT32_MAX, as a moderate position's count equals the float floor."""
    from fractions import Fraction

    from drivers.units import wrap_int32

    d = DriveModel(DM1200A, period_s=DT)
    rpc = DM1200A.rad_per_count
    d.update(0.0, 0.5, 0.0)
    assert d.position_counts == math.floor(0.5 / rpc)
    d.update(DT, 1.7e308, 0.0)
    assert d.position_counts == wrap_int32(math.floor(Fraction(1.7e308) / Fraction(rpc)))
    assert d.velocity_counts_s == INT32_MAX
    d.update(2 * DT, -1.7e308, 0.0)
    assert d.velocity_counts_s == INT32_MIN


# ----------------------------------------------------------------- many periods at once


def test_enabled_outputs_and_encoder_counts_are_the_drives_arithmetic() -> None:
    """DriveModel.enabled_outputs / encoder_counts and drivers.units.torques_to_permille (the
    offline simulation's block path) give, element by element, what the scalar path gives:
    ties of the per-mille rounding (half to even), the INT16 and max-torque clamps, the
    saturation bit, the floor of negative positions."""
    import numpy as np

    from drivers.units import torque_to_permille, torques_to_permille

    rated = DM1200A.rated_torque_Nm
    per_mille = rated / 1000.0
    torques = [0.0, 0.5 * per_mille, 1.5 * per_mille, -2.5 * per_mille, 0.4 * rated, -0.99 * rated,
               3.0 * rated, -3.0 * rated, 1e4, -1e4, 40.0 * rated]  # fmt: skip
    torques += list(np.random.default_rng(1).uniform(-2 * rated, 2 * rated, 200))
    targets = torques_to_permille(np.array(torques), rated)
    assert targets.tolist() == [torque_to_permille(x, rated) for x in torques]
    d = enabled()
    d.write_max_torque(1500)
    torque, status = d.enabled_outputs(targets)
    expected = []
    for target in targets.tolist():
        d.write_target_torque(target, 0.0)
        expected.append((d.torque_Nm, d.statusword))
    assert list(zip(torque.tolist(), status.tolist(), strict=True)) == expected
    assert {s & 0x0C00 for s in status.tolist()} == {0x0400, 0x0800}  # both cases met
    positions = np.random.default_rng(2).uniform(-50.0, 50.0, 300)
    counts = d.encoder_counts(positions).tolist()
    rad = DM1200A.rad_per_count
    assert counts == [math.floor(p / rad) for p in positions.tolist()]
    d.write_controlword(0x07, 0.0)  # switched on: no torque applied
    with pytest.raises(ValueError, match="not applying torque"):
        d.enabled_outputs(targets)
