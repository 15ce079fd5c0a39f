"""PLC codec: round trips, CRC, and a fuzz test of the streaming decoder."""
import random
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from quadrivio_plc import protocol as P

MESSAGES = [
    P.Setpoint(P.SOURCE_AUTO, 2.5, -0.25, 0.0),
    P.Setpoint(P.SOURCE_MANUAL, -1.0, 0.4, 1.0),
    P.ModeRequest(P.MODE_AUTO),
    P.Heartbeat(),
    P.State(12.34, P.MODE_AUTO, P.FAULT_WATCHDOG, 77, 2.0, 0.1, 0.3, 0.0, 2.5, 0.12),
    P.Ack(65535, P.Setpoint.TYPE, P.CLAMPED, P.MODE_SAFE),
    P.Refused(P.BUSY, "another client is connected (127.0.0.1:40000)"),
    P.Hello(bytes(range(16)), 0.2, 1.0),
    P.Auth(bytes(range(32))),
]


def approx_equal(a, b):
    assert type(a) is type(b)
    for x, y in zip(a.__dict__.values(), b.__dict__.values()):
        if isinstance(x, float):
            assert y == pytest.approx(x, rel=1e-6, abs=1e-6)  # f32 on the wire
        else:
            assert x == y


def test_crc_check_value():
    assert P.crc16(b"123456789") == 0x29B1  # CRC-16/CCITT-FALSE check value


@pytest.mark.parametrize("msg", MESSAGES)
def test_round_trip(msg):
    frame = P.encode(msg, 4242)
    assert frame[:2] == b"QV"
    dec = P.FrameDecoder()
    [(seq, out)] = dec.feed(frame)
    assert seq == 4242
    approx_equal(msg, out)
    assert dec.stats.bad_frames == 0 and dec.pending == 0


def test_byte_by_byte_and_concatenated():
    stream = b"".join(P.encode(m, k) for k, m in enumerate(MESSAGES))
    dec = P.FrameDecoder()
    got = []
    for b in stream:
        got += dec.feed(bytes([b]))
    assert [s for s, _ in got] == list(range(len(MESSAGES)))
    assert P.FrameDecoder().feed(stream) and dec.stats.bad_frames == 0


def test_rejects_are_counted_by_reason_and_skipped():
    good = P.encode(P.Heartbeat(), 1)
    bad_crc = bytearray(P.encode(P.Setpoint(1, 1.0, 0.0, 0.0), 2))
    bad_crc[10] ^= 0xFF
    bad_version = bytearray(P.encode(P.Heartbeat(), 3))
    bad_version[2] = 9
    oversized = P.HEADER.pack(P.MAGIC, P.VERSION, 0x01, 4, 5000)
    unknown = P.HEADER.pack(P.MAGIC, P.VERSION, 0x55, 5, 0)
    unknown += P.CRC.pack(P.crc16(unknown))
    short = P.HEADER.pack(P.MAGIC, P.VERSION, P.Setpoint.TYPE, 6, 3) + b"abc"
    short += P.CRC.pack(P.crc16(short))
    stream = b"garbage" + bytes(bad_crc) + bytes(bad_version) + oversized + unknown + short + good
    dec = P.FrameDecoder()
    frames = dec.feed(stream)
    assert [s for s, _ in frames] == [1]
    for reason in ("garbage", "bad checksum", "bad version", "oversized", "unknown type", "bad payload"):
        assert dec.stats.errors.get(reason, 0) >= 1, reason
    problems = dec.pop_problems()
    assert problems and dec.pop_problems() == []


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=600))
def test_fuzz_random_bytes_never_raise(data):
    dec = P.FrameDecoder()
    for seq, msg in dec.feed(data):  # whatever comes out must be a valid message
        assert 0 <= seq <= 0xFFFF and msg is not None
    # At most one incomplete frame is held, never the garbage before it.
    assert dec.pending < P.MAX_FRAME


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from(range(len(MESSAGES))), min_size=1, max_size=12),
       st.lists(st.tuples(st.integers(0, 10 ** 6), st.sampled_from(["flip", "cut", "insert"]), st.binary(max_size=8)),
                max_size=6),
       st.integers(1, 64))
def test_fuzz_corrupted_streams_recover_intact_frames(picks, damage, chunk):
    """Corrupt some frames of a stream; every frame left intact still decodes, in order."""
    frames = [bytearray(P.encode(MESSAGES[i], k)) for k, i in enumerate(picks)]
    damaged = set()
    for pos, kind, junk in damage:
        k = pos % len(frames)
        f = frames[k]
        if not f:
            continue
        damaged.add(k)
        at = pos % len(f)
        if kind == "flip":
            f[at] ^= 0x5A
        elif kind == "cut":
            del f[at:]
        else:
            f[at:at] = junk
    # A live link keeps sending: a corrupted length field at the end of the stream holds
    # the frames after it only until enough later bytes arrive to fail its checksum.
    tail = b"".join(P.encode(P.Heartbeat(), 1000 + k) for k in range(16))
    stream = b"".join(bytes(f) for f in frames) + tail
    dec = P.FrameDecoder()
    got = []
    for i in range(0, len(stream), chunk):
        got += dec.feed(stream[i:i + chunk])
    got = [(seq, msg) for seq, msg in got if seq < 1000]
    seqs = [s for s, _ in got]
    # Nothing is invented: every decoded frame is one that was sent, with its content.
    for seq, msg in got:
        assert 0 <= seq < len(frames)
        approx_equal(MESSAGES[picks[seq]], msg)
    # Intact frames survive unless damage in the frame just before swallowed their start.
    for k in range(len(frames)):
        if k not in damaged and (k == 0 or (k - 1) not in damaged):
            assert k in seqs


def test_random_garbage_between_frames_seeded():
    rng = random.Random(1)
    dec = P.FrameDecoder()
    sent = 0
    got = []
    for k in range(300):
        got += dec.feed(bytes(rng.getrandbits(8) for _ in range(rng.randint(0, 40))).replace(b"Q", b"q"))
        got += dec.feed(P.encode(P.Setpoint(P.SOURCE_AUTO, k * 0.01, 0.0, 0.0), k))
        sent += 1
    assert [s for s, _ in got] == list(range(sent))


def test_payload_struct_sizes_match_protocol_doc():
    assert P.Setpoint.FMT.size == 13
    assert P.State.FMT.size == 37
    assert P.Ack.FMT.size == 5
    assert struct.calcsize("<2sBBHH") == 8


def test_mode_names():
    assert P.parse_mode("auto") == P.MODE_AUTO
    assert P.parse_mode(" Safe ") == P.MODE_SAFE
    assert P.parse_mode("4") == P.MODE_AUTO
    assert P.parse_mode("FAST") is None
    assert P.parse_mode(9) is None


def test_rejections_are_summarised_per_reason_not_per_frame():
    """64 KiB of frames with a bad version: every one counted, one line per reason to log."""
    bad = bytearray(P.encode(P.Heartbeat(), 1))
    bad[2] = 1
    data = bytes(bad) * (65536 // len(bad))
    dec = P.FrameDecoder()
    assert dec.feed(data) == []
    assert dec.stats.errors["bad version"] == 65536 // len(bad)
    problems = dec.pop_problems()
    assert len(problems) == 2 and problems[0].startswith(f"{65536 // len(bad)} x bad version")
    assert problems[1].startswith(f"{65536 // len(bad)} x garbage")  # the rest of each frame
    assert dec.pop_problems() == [] and dec.pending < P.MAX_FRAME


def test_sequence_numbers_must_advance():
    assert P.seq_advanced(5, None) and P.seq_advanced(6, 5) and P.seq_advanced(0, 65535)
    assert not P.seq_advanced(5, 5) and not P.seq_advanced(4, 5) and not P.seq_advanced(65535, 0)
    assert not P.seq_advanced((5 + 0x8000) & 0xFFFF, 5)


def test_auth_mac_depends_on_key_and_nonce():
    n1, n2 = P.new_nonce(), P.new_nonce()
    assert n1 != n2 and len(n1) == P.NONCE_SIZE
    mac = P.auth_mac(b"k" * 20, n1)
    assert P.auth_ok(b"k" * 20, n1, mac)
    assert not P.auth_ok(b"k" * 20, n2, mac) and not P.auth_ok(b"j" * 20, n1, mac)


def test_key_files(tmp_path):
    path = tmp_path / "sub" / "plc.key"
    key = P.ensure_key(str(path))
    assert len(key) >= P.MIN_KEY_CHARS and P.load_key(str(path)) == key == P.ensure_key(str(path))
    assert (path.stat().st_mode & 0o777) == 0o600
    (tmp_path / "short.key").write_text("abc\n")
    with pytest.raises(P.KeyFileError, match="short.key holds 3 characters"):
        P.load_key(str(tmp_path / "short.key"))
    with pytest.raises(P.KeyFileError, match="missing.key does not exist"):
        P.load_key(str(tmp_path / "missing.key"))


@pytest.mark.parametrize("text, needle", [("", "holds 0 characters"), ("0123456789", "holds 10 characters"),
                                          (" \n\t  \n", "holds only whitespace")])
def test_unusable_key_files_name_the_problem(tmp_path, text, needle):
    path = tmp_path / "plc.key"
    path.write_text(text)
    with pytest.raises(P.KeyFileError, match=needle) as info:
        P.ensure_key(str(path))
    assert str(path) in str(info.value)


def test_a_directory_is_not_a_key_file(tmp_path):
    with pytest.raises(P.KeyFileError, match="is a directory"):
        P.ensure_key(str(tmp_path))


def test_key_warnings_name_a_readable_file_and_a_weak_key(tmp_path):
    good = tmp_path / "good.key"
    key = P.ensure_key(str(good))
    assert P.key_warnings(str(good), key) == []  # created 0600, random
    weak = tmp_path / "weak.key"
    weak.write_text("aaaaaaaaaaaaaaaa\n")
    weak.chmod(0o644)
    warnings = P.key_warnings(str(weak), P.load_key(str(weak)))
    assert len(warnings) == 2
    assert all(str(weak) in w for w in warnings)
    assert "readable by other users (mode 0644)" in warnings[0] and "weak key" in warnings[1]
    pattern = tmp_path / "pattern.key"
    pattern.write_text("abababababababab")
    pattern.chmod(0o600)
    assert ["weak key" in w for w in P.key_warnings(str(pattern), P.load_key(str(pattern)))] == [True]


def _msg_constants(name):
    """NAME=value constants of a .msg file of this package, read from its text."""
    import os
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "msg", name)
    out = {}
    for line in open(path):
        line = line.split("#", 1)[0].strip()
        if "=" in line:
            decl, value = line.split("=", 1)
            out[decl.split()[-1]] = int(value)
    return out


def test_protocol_constants_are_the_messages():
    """The wire's modes and fault bits are VehicleState's: a change on one side only would make
    /vehicle/state say another mode than the PLC is in."""
    c = _msg_constants("VehicleState.msg")
    modes = {k: v for k, v in c.items() if k.startswith("MODE_")}
    faults = {k: v for k, v in c.items() if k.startswith("FAULT_")}
    assert modes == {f"MODE_{name}": mode for mode, name in P.MODE_NAMES.items()}
    assert faults == {f"FAULT_{name}": bit for bit, name in P.FAULT_NAMES.items()}
