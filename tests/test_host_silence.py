"""The host-silence check shared by the CAN servers (virtual_robot.host_silence)."""

from __future__ import annotations

from virtual_robot.host_silence import HostSilence


def test_fires_once_after_the_timeout_and_again_only_after_the_host_spoke() -> None:
    silence = HostSilence(0.5)
    assert not silence.expired(100.0)  # the host never spoke: nothing to miss
    silence.heard(10.0)
    assert not silence.expired(10.5)  # exactly the timeout is not yet silence
    assert silence.expired(10.51)
    assert not silence.expired(20.0)  # once per silence
    silence.heard(20.0)
    assert not silence.expired(20.4)
    assert silence.expired(20.6)


def test_no_timeout_never_fires() -> None:
    silence = HostSilence(None)
    silence.heard(0.0)
    assert not silence.expired(1e9)
