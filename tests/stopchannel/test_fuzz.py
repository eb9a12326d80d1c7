"""Whatever bytes arrive, the channel thread survives and the next real stop is served."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from armwarden.stopchannel import StopChannel

from .conftest import TOKENS, Latch, exchange, post

VALID = b"POST /estop HTTP/1.1\r\nAuthorization: Bearer aw_operator-token\r\nContent-Length: 4\r\n\r\nwhy?"

garbage = st.one_of(
    st.binary(max_size=6000),
    st.builds(lambda cut, tail: VALID[:cut] + tail, st.integers(0, len(VALID)), st.binary(max_size=300)),
    st.builds(
        lambda head, value: head + value + b"\r\n\r\n",
        st.sampled_from([b"POST /estop HTTP/1.1\r\nContent-Length: ", b"POST /estop HTTP/1.1\r\nAuthorization: "]),
        st.binary(max_size=100),
    ),
)


@pytest.mark.timeout(120)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(chunks=st.lists(garbage, min_size=1, max_size=3))
def test_arbitrary_bytes_never_stop_the_channel(chunks: list[bytes]) -> None:
    latch = Latch()
    with StopChannel(authenticate=TOKENS.get, latch_and_stop=latch) as channel:
        for chunk in chunks:
            exchange(channel.port, chunk)
        garbage_stops = len(latch.calls)  # a generated prefix may complete the valid request
        status, _, answer = post(channel.port, b"after the noise")

        assert channel.is_serving
        assert status == 200
        assert latch.calls[garbage_stops:] == [("after the noise", "alice")]
        assert answer["event"] == garbage_stops + 1
