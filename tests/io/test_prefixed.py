"""``io.special.PrefixedRaw``: the bytes a sniffer already read, then the rest of a descriptor or a stream,
whole and in order, whatever the read sizes; a descriptor is closed with it, a stream is left open."""

from __future__ import annotations

import io
import os

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rbgp_cli.io.special import PrefixedRaw


@settings(max_examples=60, deadline=None)
@given(data=st.binary(max_size=3000), cut=st.integers(0, 3000), size=st.integers(1, 700))
def test_head_then_the_rest_of_a_stream_in_any_read_size(data, cut, size):
    cut = min(cut, len(data))
    source = io.BytesIO(data[cut:])
    raw = PrefixedRaw(data[:cut], source)
    chunks = list(iter(lambda: raw.read(size), b""))
    assert b"".join(chunks) == data
    assert all(len(c) <= size for c in chunks)
    raw.close()
    assert not source.closed  # the caller's stream stays open
    with pytest.raises(io.UnsupportedOperation):
        PrefixedRaw(b"", io.BytesIO()).fileno()


def test_head_then_the_rest_of_a_descriptor_which_closes_with_it():
    r, w = os.pipe()
    os.write(w, b"rest of it\n")
    os.close(w)
    stream = io.BufferedReader(PrefixedRaw(b"head, ", r))
    assert stream.fileno() == r and not stream.seekable()
    assert stream.read() == b"head, rest of it\n"
    stream.close()
    with pytest.raises(OSError):
        os.fstat(r)  # closed with the stream
