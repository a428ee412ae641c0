"""drivers.candump.CandumpWriter writes what python-can's CanutilsLogWriter does, byte for byte."""

from __future__ import annotations

import can
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.candump import CandumpWriter

_CLASSIC = st.builds(
    can.Message,
    timestamp=st.floats(0, 2e9, allow_nan=False),
    arbitration_id=st.integers(0, 0x7FF),
    is_extended_id=st.booleans(),
    is_remote_frame=st.booleans(),
    is_error_frame=st.booleans(),
    is_rx=st.booleans(),
    channel=st.sampled_from([None, "can0", 3, "7", "vcan1"]),
    data=st.binary(max_size=8),
)
_FD = st.builds(
    can.Message,
    timestamp=st.floats(0, 2e9, allow_nan=False),
    arbitration_id=st.integers(0, 0x7FF),
    is_extended_id=st.booleans(),
    is_rx=st.booleans(),
    is_fd=st.just(True),
    bitrate_switch=st.booleans(),
    error_state_indicator=st.booleans(),
    channel=st.sampled_from([None, "can1"]),
    data=st.sampled_from([0, 1, 8, 12, 16, 20, 24, 32, 48, 64]).flatmap(
        lambda n: st.binary(min_size=n, max_size=n)
    ),
)
_FRAMES = st.lists(st.tuples(st.integers(0, 0x7FF), st.binary(max_size=8)), max_size=4)
# one step: a Message through write_message, or a batch (possibly empty) through write_frames
_STEP = st.one_of(
    _CLASSIC,
    _FD,
    st.tuples(st.floats(0, 2e9, allow_nan=False), _FRAMES, st.booleans()),
)


@settings(max_examples=300, deadline=None)
@given(
    steps=st.lists(_STEP, max_size=12),
    channel=st.sampled_from([None, "slcan0", "0"]),
)
def test_candump_writer_writes_what_python_can_writes(steps, channel, tmp_path_factory) -> None:
    """Classic, remote, error and FD frames, extended ids, channels, batches, empty batches (no
    line and no move of the timestamp floor) and the default channel (python-can's ``vcan0``)."""
    tmp = tmp_path_factory.mktemp("log")
    kwargs = {} if channel is None else {"channel": channel}
    reference = can.CanutilsLogWriter(tmp / "ref.log", **kwargs)
    ours = CandumpWriter(tmp / "ours.log", **kwargs)
    for step in steps:
        if isinstance(step, can.Message):
            reference.on_message_received(step)
            ours.write_message(step)
            continue
        stamp, frames, rx = step
        for cob_id, data in frames:
            reference.on_message_received(
                can.Message(
                    timestamp=stamp,
                    arbitration_id=cob_id,
                    data=data,
                    is_extended_id=False,
                    is_rx=rx,
                )
            )
        ours.write_frames(stamp, frames, rx)
    reference.stop()
    ours.stop()
    assert (tmp / "ours.log").read_text() == (tmp / "ref.log").read_text()


def test_an_empty_batch_first_does_not_set_the_timestamp_floor(tmp_path) -> None:
    ours = CandumpWriter(tmp_path / "bus.log")
    ours.write_frames(10.0, [], rx=False)
    ours.write_frames(5.0, [(0x80, b"")], rx=False)
    ours.stop()
    assert (tmp_path / "bus.log").read_text() == "(5.000000) vcan0 080# T\n"
