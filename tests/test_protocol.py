"""Wire codec (protocol/codec.py) against SPEC.md: arrays, envelope, signatures, field checks."""

from __future__ import annotations

import gc
import hashlib
import hmac
import math

import msgpack
import numpy as np
import pytest

from hydrolink.protocol import codec
from hydrolink.protocol.codec import Code, ProtocolError


def roundtrip(msg: dict, key: bytes | None = None) -> dict:
    return codec.unpack(codec.pack(msg, key), key)


@pytest.mark.parametrize("arr", [
    np.arange(12, dtype=float).reshape(2, 6) / 7,
    np.array([[True, False, True, True, False, True]]),
    np.array([1 + 2j, -3.5j]),
    np.arange(5, dtype=np.int64),
    np.array(3.25),
    np.zeros((0, 6)),
    np.asfortranarray(np.arange(18.0).reshape(3, 6)),
])
def test_array_round_trip_is_exact(arr):
    wire = roundtrip({"a": arr})["a"]
    assert isinstance(wire["data"], bytes) and wire["shape"] == list(arr.shape)
    back = codec.decode_array(wire, "a", kind="")
    assert back.dtype == arr.dtype and back.shape == arr.shape
    np.testing.assert_array_equal(back, arr)


def test_sender_dtypes_are_little_endian_strings():
    assert codec.encode_array(np.zeros(2))["dtype"] == "<f8"
    assert codec.encode_array(np.zeros(2, ">f8"))["dtype"] == "<f8"
    assert codec.encode_array(np.zeros(2, bool))["dtype"] == "|b1"
    assert codec.encode_array(np.zeros(2, complex))["dtype"] == "<c16"


def test_nested_lists_and_numbers_are_accepted():
    msg = roundtrip({"position": [[0, 0.5, -1, 0, 0, 1e-3]], "x": 2})
    pos = codec.require_array(msg, "position", (1, 6))
    assert pos.dtype == np.float64 and pos[0, 2] == -1.0
    assert codec.decode_array(msg["x"], "x").shape == ()


@pytest.mark.parametrize("value, why", [
    ([[1.0, 2.0], [3.0]], "rectangular"),
    ([["a", 1.0]], "rectangular"),
    ({"dtype": "<f8", "shape": [1, 6], "data": b"\0" * 40}, "40 bytes"),
    ({"dtype": ">f8", "shape": [1, 6], "data": b"\0" * 48}, "dtype"),
    ({"dtype": "<f8", "shape": [1, -6], "data": b""}, "shape"),
    ({"dtype": "<f8", "shape": [1, 6], "data": "text"}, "bin"),
    ("abc", "must be an array"),
    ({"dtype": "<c16", "shape": [1], "data": b"\0" * 16}, "real"),
])
def test_bad_arrays_are_rejected_naming_the_field(value, why):
    with pytest.raises(ProtocolError) as err:
        codec.require_array({"velocity": value}, "velocity", (None, 6) if why != "real" else (1,))
    assert err.value.code == Code.BAD_VALUE and err.value.field == "velocity"
    assert why in err.value.message


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_values_are_rejected_with_index(bad):
    pos = np.zeros((2, 6))
    pos[1, 3] = bad
    for value in (codec.encode_array(pos), pos.tolist()):
        with pytest.raises(ProtocolError) as err:
            codec.require_array(roundtrip({"position": value}), "position", (2, 6))
        assert (err.value.code, err.value.name, err.value.field) == (5, "bad_value", "position")
        assert "[1, 3]" in err.value.message


def test_wrong_shape_names_expected_and_got():
    with pytest.raises(ProtocolError) as err:
        codec.require_array({"position": np.zeros((2, 6))}, "position", (1, 6))
    assert err.value.code == 5 and "(1, 6)" in err.value.message and "(2, 6)" in err.value.message


def test_scalar_field_helpers():
    msg = {"seq": 3, "flag": True, "t": 0.5, "name": "x", "m": {}}
    assert codec.require_int(msg, "seq", minimum=0) == 3
    assert codec.require_int(msg, "iteration", default=0) == 0
    assert codec.require_float(msg, "t") == 0.5
    assert codec.require_str(msg, "name") == "x"
    cases = [(lambda: codec.require_int(msg, "flag"), 5), (lambda: codec.require_int({"s": -1}, "s", minimum=0), 5),
             (lambda: codec.require_float({"t": math.nan}, "t"), 5), (lambda: codec.require_str(msg, "seq"), 5),
             (lambda: codec.require_int(msg, "missing"), 4), (lambda: codec.require(msg | {"n": None}, "n"), 4),
             (lambda: codec.require_map(msg, "name"), 5)]
    for fn, code in cases:
        with pytest.raises(ProtocolError) as err:
            fn()
        assert err.value.code == code


def test_unpack_rejects_garbage_and_non_maps():
    for frame in (b"\xc1\xc1garbage", b"", msgpack.packb([1, 2, 3]), msgpack.packb("hello")):
        with pytest.raises(ProtocolError) as err:
            codec.unpack(frame)
        assert err.value.code == Code.MALFORMED and err.value.name == "malformed"


@pytest.mark.parametrize("change, code, field", [
    ({"v": None}, 4, "v"), ({"v": 2}, 2, "v"), ({"v": "1"}, 2, "v"),
    ({"type": None}, 4, "type"), ({"type": "launch"}, 3, "type"), ({"type": "forces"}, 3, "type"),
    ({"msg_id": None}, 4, "msg_id"), ({"msg_id": 1.5}, 5, "msg_id"), ({"session": 7}, 5, "session"),
])
def test_envelope_checks(change, code, field):
    msg = {"v": 1, "type": "ping", "msg_id": "c-1", "session": None}
    assert codec.check_envelope(msg) == ("ping", "c-1", None)
    with pytest.raises(ProtocolError) as err:
        codec.check_envelope({**msg, **change})
    assert (err.value.code, err.value.field) == (code, field)


def test_signature_round_trip_and_rejections():
    key = b"shared-secret"
    msg = codec.message("step", "c-1", "abc", seq=1, time=0.1, position=np.ones((1, 6)))
    frame = codec.pack(msg, key)
    assert frame[-38:-32] == codec.SIG_TRAILER
    got = codec.unpack(frame, key)
    assert "sig" not in got and got["seq"] == 1
    tampered = bytearray(frame)
    tampered[frame.index(b"seq") + 3] ^= 1
    for bad, why in ((bytes(tampered), "does not match"), (codec.pack(msg), "not signed"),
                     (codec.pack(msg, b"other key"), "does not match")):
        with pytest.raises(ProtocolError) as err:
            codec.unpack(bad, key)
        assert err.value.code == Code.BAD_SIGNATURE and why in err.value.message
    assert codec.unpack(frame)["seq"] == 1  # without a key the signature is ignored


def test_signature_is_implementable_by_a_streaming_packer():
    """What a C client does (SPEC §3.3): stream the map, sig last, hash the bytes, append."""
    key = b"k"
    packer = msgpack.Packer()
    head = packer.pack_map_header(4) + packer.pack("v") + packer.pack(1) + packer.pack("type") + \
        packer.pack("ping") + packer.pack("msg_id") + packer.pack(7) + packer.pack("sig") + b"\xc4\x20"
    frame = head + hmac.new(key, head, hashlib.sha256).digest()
    assert codec.unpack(frame, key) == {"v": 1, "type": "ping", "msg_id": 7}


def test_error_reply_fields():
    err = ProtocolError(Code.OUT_OF_ORDER, "seq", "expected 3")
    reply = roundtrip(codec.error_from(err, "s-1", "c-9", "sess"))
    assert reply == {"v": 1, "type": "error", "msg_id": "s-1", "session": "sess", "parent": "c-9",
                     "code": 6, "name": "out_of_order", "field": "seq", "message": "expected 3"}
    assert codec.code_name(12345) == "internal"


def test_hot_path_codec_cost_is_small():
    """pack+unpack+validate of a one-body step is tens of µs at most (measured ≈ 8-15 µs)."""
    costs = codec._bench(n_bodies=1, repeat=2000)
    assert costs["step binary"] < 200 and costs["forces binary"] < 200


def test_error_paths_quote_keys_that_are_not_identifiers():
    """SPEC §5.6: a path splits without ambiguity, also when a map key holds dots."""
    from hydrolink.protocol.codec import key_path
    assert key_path("hdbs", "float") == "hdbs.float"
    assert key_path("hdbs", "cylinder.nc") == 'hdbs["cylinder.nc"]'
    assert key_path("hdbs", 'a "b".h5') == 'hdbs["a \\"b\\".h5"]'


def test_nil_is_absent_in_every_map_of_a_request():
    """SPEC §2: a nil field counts as absent, in nested maps too; array maps and lists are values."""
    pos = codec.encode_array(np.zeros((1, 6)))
    msg = codec.unpack(codec.pack({"v": 1, "type": "command", "msg_id": 1, "session": None, "wait": None,
                                   "commands": {"pto": {"damping": None, "stiffness": 5.0}},
                                   "position": pos, "list": [None, {"a": None}], "keep": 0}))
    got = codec.without_nil(msg)
    assert got == {"v": 1, "type": "command", "msg_id": 1, "commands": {"pto": {"stiffness": 5.0}},
                   "position": pos, "list": [None, {"a": None}], "keep": 0}
    assert codec.require_int(got, "iteration", default=0) == 0 and "wait" not in got
    deep: dict = {"x": None}
    for _ in range(3 * codec.MAX_TREE_DEPTH):
        deep = {"d": deep}
    codec.without_nil(deep)   # bounded: no recursion past MAX_TREE_DEPTH


@pytest.mark.parametrize("value,field", [(2 ** 70, "setup.last_seq"), (-2 ** 64, "setup.last_seq"),
                                         ([1, 2 ** 64], "setup.last_seq[1]"), ({"a.b": object()}, 'setup.last_seq["a.b"]')])
def test_a_value_the_wire_cannot_carry_is_refused_naming_its_field(value, field):
    """Issue 22: a welcome with an int past 64 bits raised TypeError in the server loop; the codec
    now raises EncodeError naming the field (and packs the largest ints msgpack carries)."""
    msg = codec.message("welcome", "s-1", "x" * 32, "h-1", setup={"last_seq": value, "dt": 0.1})
    with pytest.raises(codec.EncodeError) as info:
        codec.pack(msg)
    assert info.value.field == field, info.value
    for ok in (2 ** 64 - 1, -2 ** 63):
        assert codec.unpack(codec.pack(dict(msg, setup={"last_seq": ok})))["setup"]["last_seq"] == ok


def _ping_with(pad: bytes) -> bytes:
    """A ping frame with one more entry ``pad`` whose value is the raw msgpack ``pad``."""
    head = bytearray(codec.pack(codec.message("ping", "p-1", None)))
    head[0] += 1   # fixmap: one entry more
    return bytes(head) + b"\xa3pad" + pad


def _array_header(n: int) -> bytes:
    return b"\xdd" + n.to_bytes(4, "big")


def test_decoding_is_bounded_in_containers_and_entries_naming_the_bound():
    """SPEC §2: a message holds at most MAX_DECODED_CONTAINERS maps and lists and MAX_DECODED_ITEMS
    entries (issue 35 item 2: a 60 MiB ping of 63 million empty lists took 4.3 GB and 22-29 s). One
    list longer than the entries' bound is refused from its header; many lists each under it,
    together over a bound, are refused once the count passes it; each error 1 naming its bound. A
    message within the bounds decodes as it did."""
    containers, items = codec.MAX_DECODED_CONTAINERS, codec.MAX_DECODED_ITEMS
    with pytest.raises(ProtocolError) as one:
        codec.unpack(_ping_with(_array_header(63_000_000) + b"\x90" * 2 * codec.SMALL_FRAME))
    assert one.value.code == Code.MALFORMED and f"exceeds max_array_len({items})" in one.value.message
    inner = containers // 8   # 9 lists of containers/8 empty lists: over the bound on containers
    with pytest.raises(ProtocolError) as lists:
        codec.unpack(_ping_with(_array_header(9) + (_array_header(inner) + b"\x90" * inner) * 9))
    assert lists.value.code == Code.MALFORMED and lists.value.extra == {"limit": "decoded_containers",
                                                                        "maximum": containers}
    assert f"more maps and lists than a message may: at most {containers}" in lists.value.message
    nils = items // 4   # 5 lists of items/4 nils: over the bound on entries
    with pytest.raises(ProtocolError) as entries:
        codec.unpack(_ping_with(_array_header(5) + (_array_header(nils) + b"\xc0" * nils) * 5))
    assert entries.value.extra == {"limit": "decoded_items", "maximum": items}
    assert f"more entries (list items, map keys and values) than a message may: at most {items}" \
        in entries.value.message
    fits = _array_header(7) + (_array_header(inner) + b"\x90" * inner) * 7   # 7/8 of the bound: decoded
    msg = codec.unpack(_ping_with(fits))
    assert msg["type"] == "ping" and len(msg["pad"]) == 7 and all(len(x) == inner for x in msg["pad"])
    assert gc.isenabled()   # paused while decoding only


def _nested(depth: int, per: int, item: bytes) -> bytes:
    """Lists nested ``depth`` deep, each holding ``per`` copies of ``item`` then the next: none is
    complete before the innermost, so msgpack's hooks see nothing until then."""
    parts = [_array_header(per + (i < depth - 1)) + item * per for i in range(depth)]
    return b"".join(parts)


def test_objects_in_lists_not_yet_complete_are_bounded_too():
    """A frame of more than FEW_OBJECTS objects is decoded metered (codec._Metered): objects made
    in lists not yet complete count against MAX_DECODED_ITEMS (before: 57 MiB of 2-character
    strings nested 1000 deep took 1.4 GB and 3.5 s before the first hook), and such a frame is at
    most MANY_OBJECTS_BYTES (nil costs a list slot, 8 B a byte, and no object). A many-object
    frame within the bounds decodes as msgpack decodes it."""
    n = codec.MAX_DECODED_ITEMS
    with pytest.raises(ProtocolError) as strings:
        codec.unpack(_ping_with(_nested(100, n // 40, b"\xa2ab")))
    assert strings.value.extra == {"limit": "decoded_items", "maximum": n}
    with pytest.raises(ProtocolError) as nils:
        codec.unpack(_ping_with(_nested(100, codec.MANY_OBJECTS_BYTES // 90, b"\xc0")))
    assert nils.value.extra == {"limit": "many_objects_bytes", "maximum": codec.MANY_OBJECTS_BYTES}
    assert f"more than {codec.FEW_OBJECTS} msgpack objects is at most {codec.MANY_OBJECTS_BYTES} bytes" \
        in nils.value.message
    rows = np.arange(48_000.0).reshape(8_000, 6) / 7   # 56,000 entries: an array sent as lists within the bounds
    msg = codec.message("ping", "p-2", None, rows=rows.tolist(), pad=bytes(100_000))
    frame = codec.pack(msg)
    assert not codec._few_objects(frame)
    got = codec.unpack(frame)
    assert got == msgpack.unpackb(frame) and np.array_equal(codec.decode_array(got["rows"], "rows"), rows)
    assert gc.isenabled()


def test_a_received_frame_is_decoded_from_a_view_and_nothing_refers_to_it():
    """A large received frame is decoded in place (a memoryview, not copied: transport.recv_bounded);
    its bin values are copies, so the frame can be freed right after."""
    data = bytes(range(256)) * 512
    buf = bytearray(codec.pack(codec.message("upload", 1, None, sha256="0" * 64, data=data)))
    msg = codec.unpack(memoryview(buf))
    buf[-1] ^= 0xFF
    assert type(msg["data"]) is bytes and msg["data"] == data
    key = b"k" * 32
    signed = memoryview(bytearray(codec.pack(codec.message("ping", 2, None, pad=data), key)))
    assert codec.unpack(signed, key)["msg_id"] == 2


def test_over_limit_error_names_the_limit():
    exc = codec.over_limit(70 * 2**20, 64 * 2**20)
    assert (exc.code, exc.field, exc.extra) == (Code.MALFORMED, None, {"limit": "message_bytes",
                                                                         "maximum": 64 * 2**20})
    assert "message of 73400320 bytes over all its frames; at most 67108864 (64 MiB" in exc.message
    assert codec.frame_cap(64 * 2**20) == 128 * 2**20


def test_peek_reads_the_envelope_without_decoding_the_rest():
    """codec.peek: the named top-level scalar entries of a map frame, the rest jumped over by its
    headers (a 1 MB bin costs nothing); None for a frame that is not a well-formed map, a walk over
    the budget, or garbage (mutated frames never raise)."""
    import random

    msg = codec.message("hello", "h-1", None, role="multibody", scene="s" * 1000, pad=bytes(2**20), t=1.5,
                        big=2**40, neg=-3, hdbs={"a": {"x": np.arange(10.0), "l": [[1, 2], [3]], "e": {}}})
    frame = codec.pack(msg)
    keys = ("v", "type", "msg_id", "session", "role", "t", "big", "neg", "hdbs", "pad", "absent")
    assert codec.peek(frame, keys) == {"v": 1, "type": "hello", "msg_id": "h-1", "session": None,
                                       "role": "multibody", "t": 1.5, "big": 2**40, "neg": -3}
    assert codec.peek(memoryview(frame), ("msg_id",)) == {"msg_id": "h-1"}
    assert codec.peek(frame, ("v",), budget=10) is None          # hdbs needs a longer walk
    for bad in (frame[:-1], frame + b"\x00", b"\xc1", msgpack.packb([1, 2]), b""):
        assert codec.peek(bad, ("v",)) is None
    rng = random.Random(35)
    for _ in range(3000):
        mutated = bytearray(frame[:300])
        for _ in range(3):
            mutated[rng.randrange(len(mutated))] = rng.randrange(256)
        got = codec.peek(bytes(mutated), keys)
        assert got is None or isinstance(got, dict)
