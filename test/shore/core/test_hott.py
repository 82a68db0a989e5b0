"""The HoTT ESC frame codec (core/bridge/hott.py): layout, checksum, resolution, refusals."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from thruster_fdd_shore.core.bridge import hott


def test_a_frame_has_the_documented_layout() -> None:
    frame = hott.encode_esc_frame(hott.HottEscFrame(15.0, 3.25, 2100.0, 24.0, 120.0))
    assert len(frame) == hott.FRAME_LEN == 45
    assert (frame[0], frame[1], frame[3], frame[43]) == (0x7C, 0x8C, 0xC0, 0x7D)
    assert frame[6:8] == (150).to_bytes(2, "little")  # 0.1 V
    assert frame[10:12] == (12).to_bytes(2, "little")  # 10 mAh
    assert frame[12] == 24 + 20  # °C + 20
    assert frame[14:16] == (32).to_bytes(2, "little")  # 0.1 A, 3.25 rounds to 3.2
    assert frame[18:20] == (210).to_bytes(2, "little")  # 10 rpm
    assert frame[44] == sum(frame[:44]) % 256
    assert hott.REQUEST == b"\x80\x8c"


@given(
    voltage=st.floats(0, 6553.4),
    current=st.floats(0, 6553.4),
    rpm=st.floats(0, 655_340),
    temperature=st.floats(-20, 235),
)
def test_decode_returns_the_values_within_half_a_step(
    voltage: float, current: float, rpm: float, temperature: float
) -> None:
    decoded = hott.decode_esc_frame(
        hott.encode_esc_frame(hott.HottEscFrame(voltage, current, rpm, temperature))
    )
    assert decoded.voltage_v == pytest.approx(voltage, abs=0.05 + 1e-9)
    assert decoded.current_a == pytest.approx(current, abs=0.05 + 1e-9)
    assert decoded.rpm == pytest.approx(rpm, abs=5 + 1e-9)
    assert decoded.temperature_c == pytest.approx(temperature, abs=0.5 + 1e-9)


@given(offset=st.integers(0, hott.FRAME_LEN - 1), bit=st.integers(0, 7))
def test_every_single_bit_error_is_refused(offset: int, bit: int) -> None:
    data = bytearray(hott.encode_esc_frame(hott.HottEscFrame(14.8, 2.0, 2500.0, 30.0)))
    data[offset] ^= 1 << bit
    with pytest.raises(ValueError, match=r"byte|checksum"):
        hott.decode_esc_frame(bytes(data))


@pytest.mark.parametrize(
    ("frame", "words"),
    [
        (hott.HottEscFrame(float("nan"), 0.0, 0.0, 20.0), "voltage_v=nan is not finite"),
        (hott.HottEscFrame(15.0, -0.1, 0.0, 20.0), "current_a=-0.1 outside 0..6553.5"),
        (hott.HottEscFrame(15.0, 0.0, 1e6, 20.0), "rpm=1000000.0 outside 0..655350"),
        (hott.HottEscFrame(15.0, 0.0, 0.0, -21.0), "temperature_c=-21.0 outside -20..235"),
    ],
)
def test_values_the_wire_cannot_carry_are_refused(frame: hott.HottEscFrame, words: str) -> None:
    with pytest.raises(ValueError, match=words.replace(".", r"\.")):
        hott.encode_esc_frame(frame)


def test_a_short_frame_is_refused_with_its_length() -> None:
    with pytest.raises(ValueError, match="45 bytes, got 44"):
        hott.decode_esc_frame(bytes(44))
