"""mission.link.signing: key files, signing state, frame signing and the checks of received frames.

Key files are read by :mod:`wire.signing`, the one reader of the ground station and the mock.
"""
from __future__ import annotations

import datetime
import hashlib
import os

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav

from mission.core.signing_config import signing_config_from_table
from mission.link import signing as sg
from wire.signing import SigningError, SigningWarning, load_key_file, passphrase_to_key, signing_timestamp

KEY = bytes(range(1, 33))
OTHER_KEY = bytes(range(101, 133))
NOW_S = 1_763_700_000.0


def _key_file(tmp_path, data: bytes, mode: int = 0o600, name: str = "mavlink.key"):
    p = tmp_path / name
    p.write_bytes(data)
    os.chmod(p, mode)
    return p


def _gcs(config, state=None, sysid=255, compid=190):
    enc = mav.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    if config is not None:
        sg.apply_signing(enc, state if state is not None else config.new_state(NOW_S))
    return enc


def _arm(enc, target=1):
    msg = enc.command_long_encode(target, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    return msg.pack(enc)


# ------------------------------------------------------------------ key files
@pytest.mark.parametrize("data,expected", [
    (KEY.hex().encode(), KEY),
    (KEY.hex().upper().encode() + b"\n", KEY),
    (b"  " + KEY.hex().encode() + b"\r\n", KEY),
    (KEY, KEY),                                                     # raw, not printable
    (b"correct horse battery staple\n", hashlib.sha256(b"correct horse battery staple").digest()),
    (b"correct horse battery staple", hashlib.sha256(b"correct horse battery staple").digest()),
    (b"p\xc3\xa4ssphrase\r\n", hashlib.sha256("pässphrase".encode()).digest()),
    (b"x" * 32 + b"\n", hashlib.sha256(b"x" * 32).digest()),          # 32 chars + newline
])
def test_key_file_formats(tmp_path, data, expected):
    p = _key_file(tmp_path, data)
    assert load_key_file(p) == expected


def test_passphrase_key_is_mavproxys():
    # MAVProxy "signing setup PASSPHRASE": key = sha256(passphrase)
    assert passphrase_to_key("swarm") == hashlib.sha256(b"swarm").digest()
    with pytest.raises(SigningError, match="non-empty"):
        passphrase_to_key("")


@pytest.mark.parametrize("data,mode,match", [
    (KEY.hex().encode(), 0o644, "world-readable.*chmod 600"),
    (b"", 0o600, "empty"),
    (b"\n\n", 0o600, "empty"),
    (b"line one\nline two\n", 0o600, "several lines"),
    (b"A" * 32, 0o600, "ambiguous"),
    (b"00" * 32, 0o600, "all-zero"),
    (b"\xff\xfe" * 20, 0o600, "neither 64 hex"),
    (b"x" * 5000, 0o600, "5000 bytes"),
])
def test_key_file_errors_are_clear(tmp_path, data, mode, match):
    p = _key_file(tmp_path, data, mode)
    with pytest.raises(SigningError, match=match):
        load_key_file(p)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(SigningError, match="nope.key.*No such file"):
        load_key_file(tmp_path / "nope.key")
    with pytest.raises(SigningError, match="not a regular file"):
        load_key_file(tmp_path)


def test_readable_key_files_warn(tmp_path):
    with pytest.warns(SigningWarning, match="group-readable"):
        assert load_key_file(_key_file(tmp_path, KEY.hex().encode(), 0o640)) == KEY
    with pytest.warns(SigningWarning, match="world-readable"):
        key = load_key_file(_key_file(tmp_path, KEY.hex().encode(), 0o644, "b.key"),
                               allow_world_readable=True)
    assert key == KEY


# ------------------------------------------------------------------ configuration
def test_config_hides_the_key_and_validates():
    cfg = sg.SigningConfig(KEY, link_id=3)
    assert KEY.hex() not in repr(cfg) and str(list(KEY)) not in repr(cfg)
    assert cfg.fingerprint in repr(cfg) and cfg.fingerprint != sg.SigningConfig(OTHER_KEY).fingerprint
    assert cfg.allows_unsigned(mav.MAVLINK_MSG_ID_RADIO_STATUS)
    assert not cfg.allows_unsigned(mav.MAVLINK_MSG_ID_HEARTBEAT)
    assert sg.SigningConfig(KEY, allow_unsigned=frozenset({"*"})).allows_unsigned(76)


@pytest.mark.parametrize("kwargs,match", [
    ({"key": b"short"}, "32 bytes"),
    ({"key": bytes(32)}, "all-zero"),
    ({"key": KEY, "link_id": 256}, "link_id"),
    ({"key": KEY, "link_id": True}, "link_id"),
    ({"key": KEY, "allow_unsigned": frozenset({"NOT_A_MESSAGE"})}, "NOT_A_MESSAGE"),
])
def test_bad_config(kwargs, match):
    with pytest.raises(SigningError, match=match):
        sg.SigningConfig(**kwargs)


def test_security_table(tmp_path):
    _key_file(tmp_path, b"my passphrase\n", name="fleet.key")
    cfg = signing_config_from_table({"signing_key_file": "fleet.key", "signing_link_id": 7,
                                        "allow_unsigned": ["RADIO_STATUS"], "setup_signing": False},
                                       tmp_path)
    assert cfg.key == hashlib.sha256(b"my passphrase").digest()
    assert (cfg.link_id, cfg.allow_unsigned, cfg.send_setup) == (7, {"RADIO_STATUS"}, False)
    assert cfg.key_file == str(tmp_path / "fleet.key")
    assert signing_config_from_table({}, tmp_path) is None


@pytest.mark.parametrize("table,keys", [
    ({"signing_key_file": "missing.key"}, ["security.signing_key_file"]),
    ({"signing_key_file": 3}, ["security.signing_key_file"]),
    ({"signing_link_id": 1}, ["security.signing_key_file"]),
    ({"signing_key_file": "fleet.key", "signing_link_id": -1, "allow_unsigned": ["FOO"],
      "setup_signing": "yes", "colour": 1},
     ["security.colour", "security.signing_link_id", "security.allow_unsigned",
      "security.setup_signing"]),
])
def test_security_table_lists_every_problem(tmp_path, table, keys):
    _key_file(tmp_path, b"my passphrase\n", name="fleet.key")
    with pytest.raises(SigningError, match="invalid \\[security\\]") as info:
        signing_config_from_table(table, tmp_path)
    assert [k for k, _ in info.value.problems] == keys


# ------------------------------------------------------------------ timestamps and frames
@pytest.mark.parametrize("when,expected", [
    (datetime.datetime(2015, 1, 1, tzinfo=datetime.timezone.utc), 0),
    (datetime.datetime(2015, 1, 1, 0, 0, 1, tzinfo=datetime.timezone.utc), 100_000),
    (datetime.datetime(2014, 6, 1, tzinfo=datetime.timezone.utc), 0),
    (datetime.datetime(2025, 1, 1, tzinfo=datetime.timezone.utc), 3653 * 86400 * 100_000),
])
def test_signing_timestamp_units(when, expected):
    assert signing_timestamp(when.timestamp()) == expected


def test_refresh_timestamp_never_goes_back():
    state = sg.SigningConfig(KEY).new_state(NOW_S)
    start = state.timestamp
    assert sg.refresh_timestamp(state, NOW_S - 100.0) == start
    assert sg.refresh_timestamp(state, NOW_S + 1.0) == start + 100_000


@pytest.mark.parametrize("make", [
    lambda e: e.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
    lambda e: e.heartbeat_encode(6, 8, 0, 0, 4, 3),
    lambda e: e.set_position_target_local_ned_encode(5, 1, 1, 1, 0xDF8, 1.5, -2, -10, 0, 0, 0, 0, 0, 0, 0, 0),
])
def test_sign_frame_is_what_pymavlink_sends(make):
    cfg = sg.SigningConfig(KEY, link_id=4)
    a, b = cfg.new_state(NOW_S), cfg.new_state(NOW_S)
    signed = make(_gcs(cfg, a)).pack(_gcs(cfg, a))
    plain_msg = make(_gcs(None))
    by_hand = sg.sign_frame(plain_msg.pack(_gcs(None)), plain_msg.crc_extra, b)
    assert by_hand == signed
    assert a.timestamp == b.timestamp == signing_timestamp(NOW_S) + 1
    with pytest.raises(SigningError, match="unsigned MAVLink 2 frame"):
        sg.sign_frame(signed, plain_msg.crc_extra, b)


def test_shared_state_keeps_timestamps_monotonic_per_link():
    cfg = sg.SigningConfig(KEY)
    state = cfg.new_state(NOW_S)
    encoders = [_gcs(cfg, state) for _ in range(3)]
    stamps = [int.from_bytes(_arm(encoders[i % 3])[-12:-6], "little") for i in range(9)]
    assert stamps == sorted(set(stamps))


def test_setup_signing_message_round_trip():
    cfg = sg.SigningConfig(KEY)
    state = cfg.new_state(NOW_S)
    msg = sg.setup_signing_message(3, cfg.key, state.timestamp)
    parser = mav.MAVLink(None)
    got = parser.parse_buffer(msg.pack(_gcs(None)))[0]
    assert got.get_type() == "SETUP_SIGNING"
    assert (got.target_system, got.target_component) == (3, 1)
    assert bytes(got.secret_key) == KEY and got.initial_timestamp == signing_timestamp(NOW_S)
    off = parser.parse_buffer(sg.disable_signing_message(3).pack(_gcs(None)))[0]
    assert not any(off.secret_key) and off.initial_timestamp == 0
    with pytest.raises(SigningError, match="disable_signing_message"):
        sg.setup_signing_message(3, bytes(32), 0)


# ------------------------------------------------------------------ checking received frames
def _verifier(**kw):
    cfg = sg.SigningConfig(KEY, **kw)
    return sg.SignatureVerifier(cfg, cfg.new_state(NOW_S))


def test_verifier_accepts_signed_and_rejects_with_reasons():
    v = _verifier()
    good = sg.SigningConfig(KEY)
    sender = _gcs(good, good.new_state(NOW_S + 1.0), sysid=1, compid=1)
    first = _arm(sender)
    assert v.check_frame(first) is None
    assert v.check_frame(_arm(sender)) is None
    assert v.check_frame(first) == "replayed"                       # exact bytes again
    assert v.check_frame(_arm(_gcs(sg.SigningConfig(OTHER_KEY), sysid=1, compid=1))) == "bad_signature"
    assert v.check_frame(_arm(_gcs(None, sysid=1, compid=1))) == "unsigned"
    radio = _gcs(None, sysid=51, compid=68)
    assert v.check_frame(radio.radio_status_encode(200, 190, 90, 5, 3, 0, 0).pack(radio)) is None
    v1 = _gcs(None, sysid=1, compid=1)
    assert v.check_frame(v1.heartbeat_encode(2, 3, 0, 0, 4, 3).pack(v1, force_mavlink1=True)) == "unsigned"
    assert v.counters == {"accepted": 2, "replayed": 1, "bad_signature": 1, "unsigned": 2,
                          "unsigned_allowed": 1}
    assert v.unsigned_sysids == {1, 51} and v.signed_sysids == {1} and v.badly_signed_sysids == {1}
    assert v.needs_setup(51) and not v.needs_setup(1) and not v.needs_setup(2)
    assert "unsigned" in v.diagnose(51) and v.diagnose(1) == "" and v.diagnose(2) == ""


def test_verifier_tampered_timestamp_and_stale_new_stream():
    v = _verifier()
    cfg = sg.SigningConfig(KEY)
    frame = bytearray(_arm(_gcs(cfg, cfg.new_state(NOW_S), sysid=1, compid=1)))
    frame[-8] ^= 0x01                                               # timestamp byte
    assert v.check_frame(bytes(frame)) == "bad_signature"
    stale = _arm(_gcs(cfg, cfg.new_state(NOW_S - 120.0), sysid=2, compid=1))
    assert v.check_frame(stale) == "replayed"                        # 2 min behind, new stream
    recent = _arm(_gcs(cfg, cfg.new_state(NOW_S - 30.0), sysid=3, compid=1))
    assert v.check_frame(recent) is None
    assert v.check_frame(_arm(_gcs(sg.SigningConfig(OTHER_KEY), sysid=4, compid=1))) == "bad_signature"
    assert "another key" in v.diagnose(4)


def test_forged_frame_does_not_poison_the_stream():
    v = _verifier()
    cfg = sg.SigningConfig(KEY)
    genuine = _gcs(cfg, cfg.new_state(NOW_S), sysid=1, compid=1)
    assert v.check_frame(_arm(genuine)) is None
    forger = sg.SigningConfig(OTHER_KEY).new_state(NOW_S + 10_000.0)  # far-future timestamp
    forged = _arm(_gcs(sg.SigningConfig(OTHER_KEY), forger, sysid=1, compid=1))
    assert v.check_frame(forged) == "bad_signature"
    assert v.check_frame(_arm(genuine)) is None


def test_verifier_follows_the_highest_good_timestamp():
    v = _verifier()
    cfg = sg.SigningConfig(KEY)
    ahead = cfg.new_state(NOW_S + 500.0)
    assert v.check_frame(_arm(_gcs(cfg, ahead, sysid=1, compid=1))) is None
    assert v.state.timestamp == ahead.timestamp - 1


def test_verifier_checks_decoded_messages():
    v = _verifier()
    parser = mav.MAVLink(None)
    parser.robust_parsing = True
    cfg = sg.SigningConfig(KEY)
    msgs = parser.parse_buffer(_arm(_gcs(cfg, sysid=1, compid=1)) + _arm(_gcs(None, sysid=1, compid=1)))
    assert [v.check(m) for m in msgs] == [None, "unsigned"]


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_verifier_never_raises_on_garbage(data):
    v = _verifier()
    assert v.check_frame(data) in (None, "unsigned", "bad_signature", "replayed")
    assert sum(v.counters.values()) == 1
