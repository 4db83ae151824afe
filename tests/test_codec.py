"""The codec of parameter messages: quantisation, deltas to the receiver's copy, sparsification with the rest
carried, the lossless stage; both ends holding the same copy; every coded field checked."""

from __future__ import annotations

import struct
import zlib
from dataclasses import replace

import numpy as np
import pytest

from mapping.team import Channel, ChannelConfig, InstancePayload, MessageError, ParameterMessage, RoundPlan
from mapping.team import from_bytes, to_bytes
from mapping.team.codec import (CodedCloud, coded_arrays, decode_vector, dequantise, encode_cloud, encode_vector,
                                observed_change, pack_unsigned, quantise, unpack_unsigned, vector_bytes)
from mapping.team.config import CodecConfig, ExchangeConfig
from mapping.team.message_checks import MessageRules
from mapping.team.wire import ENVELOPE, MAX_INFLATION, seal, unseal
from tests.team_helpers import rewrite_header as _rewrite, tiny_team


def _payload(iid=3, size=300, code=None, feature=True):
    rng = np.random.default_rng(iid)
    params = rng.normal(size=size).astype(np.float32)
    return InstancePayload(iid, "object", params, np.zeros(3, np.float32), np.ones(3, np.float32),
                           np.full(3, 0.5, np.float32), 0.75, 1, 2, "a red mug",
                           rng.normal(size=8).astype(np.float32) if feature else None, 0.4, None, None, code)


# ---- the codec's arithmetic ------------------------------------------------------------------------------
@pytest.mark.parametrize("bits", [4, 8])
def test_quantised_values_are_within_half_a_step_of_their_block(bits):
    rng = np.random.default_rng(0)
    values = (rng.normal(size=1000) * np.repeat([1e-3, 1.0, 50.0, 0.0], 250)).astype(np.float32)
    codes, scales = quantise(values, bits, 64)
    assert codes.dtype == np.uint8 and len(codes) == -(-1000 * bits // 8) and len(scales) == -(-1000 // 64)
    back = dequantise(codes, scales, bits, 64, 1000)
    step = np.repeat(scales, 64)[:1000]
    assert np.all(np.abs(back - values) <= step / 2 + 1e-7)
    assert np.all(back[750:] == 0)  # a block of zeros has scale 0 and decodes to zeros


def test_four_bit_codes_pack_two_a_byte_and_unpack_exactly():
    q = np.arange(15, dtype=np.uint8).repeat(3)
    assert np.array_equal(unpack_unsigned(pack_unsigned(q, 4), 4, len(q)), q)


def test_sparse_deltas_carry_what_they_leave_out_and_never_drift():
    """Repeated deltas against the receiver's copy, 10 % of the entries a message at 4 bits: the copy reaches
    a still target (error feedback), follows a moving one without drifting, and the sender's reconstruction is
    the receiver's bit for bit."""
    rng = np.random.default_rng(1)
    target = rng.normal(size=2000).astype(np.float32)
    coded, copy = encode_vector(0.5 * target, 8, 64)  # a stale first copy
    receiver = decode_vector(from_bytes(to_bytes(ParameterMessage(0, 1, 0, [_payload(3, 2000, coded)]))).instances[0]
                             .params_code)
    assert np.array_equal(receiver, copy)
    errors = []
    for r in range(1, 80):
        if r > 40:  # then it keeps moving
            target = (target + rng.normal(size=2000).astype(np.float32) * 1e-3).astype(np.float32)
        coded, copy_next = encode_vector(target, 4, 64, copy, r - 1, keep=0.1)
        assert coded.kept == 200 and coded.base == r - 1
        back = from_bytes(to_bytes(ParameterMessage(0, 1, r, [_payload(3, 2000, coded)]))).instances[0]
        receiver = (receiver + back.params).astype(np.float32)  # the receiver adds the delta to its copy
        assert np.array_equal(receiver, copy_next)
        copy = copy_next
        errors.append(float(np.abs(copy - target).max()))
    assert errors[39] < 0.01 * errors[0]  # everything left out went later
    assert max(errors[40:]) < 0.01 and errors[-1] < 2 * errors[45]  # following, not drifting


def test_a_mask_or_positions_whichever_is_smaller():
    values = np.arange(800, dtype=np.float32)
    few, _ = encode_vector(values, 8, 64, np.zeros(800, np.float32), 0, keep=0.01)
    many, _ = encode_vector(values, 8, 64, np.zeros(800, np.float32), 0, keep=0.5)
    assert coded_arrays("0.params", few)[0]["index"] == "index" and coded_arrays("0.params", many)[0]["index"] == "mask"
    assert vector_bytes(800, 8, 64, 400) == 400 + 4 * 7 + 100 and vector_bytes(800, 32, 64) == 3200


def test_clouds_travel_as_integers_over_their_own_box():
    rng = np.random.default_rng(4)
    points = (rng.random((500, 3)) * [4.0, 0.5, 2.0] + [1.0, -3.0, 0.2]).astype(np.float32)
    for bits, worst in ((16, 4.0 / 65535), (8, 4.0 / 255)):
        codes, frame, held = encode_cloud(points, bits)
        assert codes.dtype == (np.uint16 if bits == 16 else np.uint8)
        assert np.abs(held - points).max() <= worst / 2 + 1e-6
        payload = replace(_payload(3), cloud=held, cloud_code=CodedCloud(codes, frame, bits))
        back = from_bytes(to_bytes(ParameterMessage(0, 1, 2, [payload]))).instances[0]
        assert np.array_equal(back.cloud, held)  # the receiver decodes what the sender computed


def test_an_observed_space_travels_as_its_change_to_the_receivers_copy():
    from mapping.model.observed import FREE, SURFACE, ObservedSpace

    space = ObservedSpace.empty(0.05)
    space.cover(np.zeros(3), np.ones(3))
    space.mark(np.array([[0.5, 0.5, 0.5]]), SURFACE)
    copy = space.copy()
    assert observed_change(space, copy) == (None, "held")
    assert observed_change(space, None)[1] == "whole"
    space.mark(np.array([[0.2, 0.2, 0.2]]), FREE)
    space.cover(np.zeros(3), np.full(3, 1.5))  # the grid grew too
    change, form = observed_change(space, copy)
    assert form == "delta" and int((change.states > 0).sum()) == 1  # only the new free cell
    merged = copy.copy()
    merged.merge(change)
    assert np.array_equal(merged.states, space.states) and np.array_equal(merged.origin, space.origin)
    assert len(change.to_bytes()) < len(space.to_bytes())


# ---- the wire -----------------------------------------------------------------------------------------------
def test_sealed_messages_round_trip_and_are_smaller():
    coded, _ = encode_vector(np.zeros(300, np.float32), 8, 64)
    plain = ParameterMessage(0, 1, 2, [_payload(3, code=coded), _payload(4, feature=False)])
    sealed = replace(plain, lossless="zlib")
    data = to_bytes(sealed)
    assert data.startswith(ENVELOPE) and len(data) < len(to_bytes(plain))
    back = from_bytes(data)
    assert back.lossless == "zlib" and back.instances[1].caption_feature is None
    assert to_bytes(back) == data


@pytest.mark.parametrize("change, error", [
    (lambda d: d[:len(ENVELOPE) + 5], "truncated message"),
    (lambda d: d[:len(ENVELOPE)] + bytes([9]) + d[len(ENVELOPE) + 1:], "unknown method"),
    (lambda d: d[:len(ENVELOPE) + 1] + struct.pack("<Q", 2**40) + d[len(ENVELOPE) + 9:], "announces"),
    (lambda d: d[:len(ENVELOPE) + 1] + struct.pack("<Q", 12) + d[len(ENVELOPE) + 9:], "inflates to 13\\+ bytes"),
    (lambda d: d[:-20], "does not inflate|inflates to"),
])
def test_bad_envelopes_are_refused(change, error):
    data = to_bytes(ParameterMessage(0, 1, 2, [_payload(3)], lossless="zlib"))
    with pytest.raises(MessageError, match=error):
        from_bytes(change(data))


def test_a_body_that_would_inflate_past_its_limit_is_refused_unexpanded():
    bomb = zlib.compress(bytes(200 << 20), 9)  # 200 MB of zeros in about 200 kB
    data = ENVELOPE + bytes([1]) + struct.pack("<Q", 200 << 20) + bomb
    assert (200 << 20) > MAX_INFLATION * len(data)
    with pytest.raises(MessageError, match="announces"):
        unseal(data)
    lying = ENVELOPE + bytes([1]) + struct.pack("<Q", 1000) + bomb  # says small, inflates big: stops at 1001
    with pytest.raises(MessageError, match="inflates to 1001\\+ bytes"):
        unseal(lying)
    with pytest.raises(MessageError, match="inside a compressed"):
        unseal(seal(seal(to_bytes(ParameterMessage(0, 1, 2, [_payload(3)])), "zlib"), "zlib"))


def _code_meta(key, value):
    def change(h):
        h["scalars"]["instances"][0]["params_code"][key] = value
        return h
    return change


def _array_entry(suffix, index, value):
    def change(h):
        entry = next(e for e in h["arrays"] if e[0] == f"0.params.{suffix}")
        entry[index] = value
        return h
    return change


@pytest.mark.parametrize("change, error", [
    (_code_meta("bits", 5), "bit width 5"),
    (_code_meta("bits", True), "bit width True"),
    (_code_meta("block", 0), "block 0"),
    (_code_meta("n", 299), "length 299"),
    (_code_meta("kept", 301), "301 values kept"),
    (_code_meta("base", -1), "base -1"),
    (_code_meta("index", "all"), "values kept of 300 as 'all'"),
    (_code_meta("extra", 1), "expected the fields"),
    (_array_entry("q", 2, [10]), "expected \\(30,\\) uint8"),
    (_array_entry("mask", 2, [37]), "array 0.params.mask"),
])
def test_each_coded_field_is_checked(change, error):
    coded, _ = encode_vector(np.arange(300, dtype=np.float32), 8, 64, np.zeros(300, np.float32), 4, keep=0.1)
    data = to_bytes(ParameterMessage(0, 1, 5, [_payload(3, code=coded)]))
    rules = MessageRules(param_counts={"object": 300, "structure": 300}, feature_dim=8)
    assert from_bytes(data, rules).instances[0].params_code.kept == 30
    with pytest.raises(MessageError, match=error):
        from_bytes(_rewrite(data, change), rules)


def test_bad_scales_and_positions_are_refused():
    coded, _ = encode_vector(np.arange(300, dtype=np.float32), 8, 64, np.zeros(300, np.float32), 4, keep=0.02)
    assert coded_arrays("0.params", coded)[0]["index"] == "index"
    for scales, index, error in [(np.array([np.nan], np.float32), coded.index, "scales must be finite"),
                                 (-np.ones(1, np.float32), coded.index, "scales must be finite"),
                                 (coded.scales, coded.index[::-1].copy(), "positions must increase"),
                                 (coded.scales, coded.index + 100, "positions must increase and lie in")]:
        bad = replace(coded, scales=scales, index=index)
        with pytest.raises(MessageError, match=error):
            from_bytes(to_bytes(ParameterMessage(0, 1, 5, [_payload(3, code=bad)])))
    with pytest.raises(MessageError, match="only a delta may leave entries out"):
        from_bytes(to_bytes(ParameterMessage(0, 1, 5, [_payload(3, code=replace(coded, base=None))])))
    whole, _ = encode_vector(np.arange(300, dtype=np.float32), 32, 64)
    with pytest.raises(MessageError, match="non-finite"):
        from_bytes(to_bytes(ParameterMessage(0, 1, 5, [_payload(3, code=replace(whole, codes=np.full_like(whole.codes, np.inf)))])))


def test_bad_clouds_and_held_flags_are_refused():
    codes, frame, held = encode_cloud(np.random.default_rng(0).random((40, 3)).astype(np.float32), 16)
    good = replace(_payload(3), cloud=held, cloud_code=CodedCloud(codes, frame, 16))
    for bad, error in [(replace(good, cloud_code=CodedCloud(codes, frame[::-1].copy(), 16)), "low below high"),
                       (replace(good, cloud_code=CodedCloud(codes.astype(np.uint8), frame, 16)), "uint16"),
                       (replace(good, cloud_code=CodedCloud(codes[:, :2].copy(), frame, 16)), "uint16")]:
        with pytest.raises(MessageError, match=error):
            from_bytes(to_bytes(ParameterMessage(0, 1, 5, [bad])))

    def meta(key, value):
        def change(h):
            h["scalars"]["instances"][0][key] = value
            return h
        return change

    data = to_bytes(ParameterMessage(0, 1, 5, [good]))
    for change, error in [(meta("cloud_bits", 12), "cloud_bits: 12"), (meta("observed_code", "maybe"), "'held' \\(with"),
                          (meta("cloud", False), "cloud_bits")]:
        with pytest.raises(MessageError, match=error):
            from_bytes(_rewrite(data, change))


def test_a_sparse_delta_cannot_ask_for_an_unbounded_vector():
    """Where the receiver leaves the length open, a part names at most 32 values a byte it carries (+1024): 616
    bytes asked for 2^24 values (64 MB decoded) before."""
    coded, _ = encode_vector(np.ones(300, np.float32), 8, 64, np.zeros(300, np.float32), 4, keep=0.01)
    data = _rewrite(to_bytes(ParameterMessage(0, 1, 5, [_payload(3, code=coded)])), _code_meta("n", 2**24))
    with pytest.raises(MessageError, match="at most 1632"):
        from_bytes(data, MessageRules())
    still = np.zeros(300, np.float32)
    empty, _ = encode_vector(still, 8, 64, still, 4)  # nothing moved: no entries at all
    assert empty.kept == 0 and empty.index is not None
    data = _rewrite(to_bytes(ParameterMessage(0, 1, 5, [_payload(3, code=empty)])), _code_meta("n", 2**24))
    with pytest.raises(MessageError, match="at most 1024"):
        from_bytes(data, MessageRules())


def test_codes_whose_values_overflow_and_clouds_whose_span_overflows_are_refused():
    coded, _ = encode_vector(np.ones(300, np.float32), 8, 64)
    huge = replace(coded, scales=np.full_like(coded.scales, 3e38), codes=np.full_like(coded.codes, 255))
    with pytest.raises(MessageError, match="not finite"):
        from_bytes(to_bytes(ParameterMessage(0, 1, 5, [_payload(3, code=huge)])))
    codes, _, held = encode_cloud(np.random.default_rng(0).random((40, 3)).astype(np.float32), 16)
    far = np.array([-3e38] * 3 + [3e38] * 3, np.float32)
    bad = replace(_payload(3), cloud=held, cloud_code=CodedCloud(codes, far, 16))
    with pytest.raises(MessageError, match="span is not finite"):
        from_bytes(to_bytes(ParameterMessage(0, 1, 5, [bad])))


def test_a_team_whose_codec_is_off_refuses_coded_and_compressed_messages():
    rules = MessageRules(coded=False)
    coded, _ = encode_vector(np.ones(300, np.float32), 8, 64)
    with pytest.raises(MessageError, match="codec is off"):
        from_bytes(to_bytes(ParameterMessage(0, 1, 5, [_payload(3, code=coded)])), rules)
    with pytest.raises(MessageError, match="codec is off"):
        from_bytes(to_bytes(ParameterMessage(0, 1, 5, [_payload(3)], lossless="zstd")), rules)
    assert from_bytes(to_bytes(ParameterMessage(0, 1, 5, [_payload(3)])), rules).instances[0].params_code is None


def test_still_instances_compress_within_the_inflation_bound():
    """Ninety instances that did not move: their deltas travel as no entries, so the sealed message stays
    under the inflation bound (a run of 4 MB of zeros compressed 2,000 times before)."""
    payloads = []
    for k in range(90):
        vector = np.random.default_rng(k).normal(size=11_300).astype(np.float32)
        code, _ = encode_vector(vector, 32, 64, vector, 0)
        payloads.append(replace(_payload(k, 11_300, code), params=vector, caption_feature=None))
    data = to_bytes(ParameterMessage(0, 1, 1, payloads, 1, "zstd"))
    assert len(unseal(data)) < MAX_INFLATION * len(data)
    rules = MessageRules(param_counts={"object": 11_300, "structure": 30_788}, feature_dim=8)  # a team's rules
    assert len(from_bytes(data, rules).instances) == 90


# ---- the settings ------------------------------------------------------------------------------------------
def test_codec_settings_are_checked_where_they_are_made():
    assert not CodecConfig().active and CodecConfig(bits=8).active
    with pytest.raises(ValueError, match="bits must be one of"):
        CodecConfig(bits=7)
    with pytest.raises(ValueError, match="needs team.exchange.codec.delta"):
        CodecConfig(keep=0.5)
    with pytest.raises(ValueError, match="lossless must be one of"):
        CodecConfig(lossless="lzma")
    with pytest.raises(ValueError, match="cloud_bits must be one of"):
        CodecConfig(cloud_bits=4)
    with pytest.raises(ValueError, match="give team.exchange.codec.bits=16"):
        ExchangeConfig(float16=True, codec=CodecConfig(bits=8))


# ---- a team with the codec -----------------------------------------------------------------------------------
def _team(tiny_world, codec: CodecConfig, success: float = 1.0):
    exchange = ExchangeConfig(codec=codec)
    team, _ = tiny_team(tiny_world, exchange=exchange, channel=ChannelConfig(success_probability=success))
    return team


def _copies_agree(team) -> int:
    """Every copy a sender believes a receiver holds is the receiver's, bit for bit; returns how many."""
    checked = 0
    for sender in team.members:
        for receiver, copies in sender.sent_vectors.items():
            held = team.members[receiver].held.get(sender.index, {})
            for iid, vector in copies.items():
                assert iid in held and np.array_equal(held[iid].params, vector), (sender.index, receiver, iid)
                assert team.members[receiver].held_at[sender.index][iid] == sender.sent_rounds[receiver][iid]
                checked += 1
            for iid, feature in sender.sent_features.get(receiver, {}).items():
                assert np.array_equal(held[iid].caption_feature, feature)
            for iid, space in sender.sent_observed.get(receiver, {}).items():
                there = held[iid].observed
                assert np.array_equal(there.origin, space.origin) and np.array_equal(there.states, space.states)
    return checked


def test_a_coded_team_holds_the_senders_copies_exactly_over_lossy_links(tiny_world):
    codec = CodecConfig(bits=8, feature_bits=8, delta=True, keep=0.25, cloud_bits=16, lossless="zstd")
    plain, coded, lossy = _team(tiny_world, CodecConfig()), _team(tiny_world, codec), _team(tiny_world, codec, 0.5)
    sent_plain = sent_coded = 0
    for _ in range(3):
        sent_plain += sum(plain.round(RoundPlan.always(2)).bytes_sent)
        sent_coded += sum(coded.round(RoundPlan.always(2)).bytes_sent)
        lossy.round(RoundPlan.always(2))
        assert _copies_agree(coded) > 0
        _copies_agree(lossy)
    assert sent_coded < 0.3 * sent_plain
    assert any(m.held for m in coded.members)
    # later messages left out what the receivers held unchanged
    message = coded.members[0].parameter_message(1, 3, 1)
    assert all(inst.caption_feature is None for inst in message.instances if inst.instance_id in
               coded.members[1].held[0])


def test_a_delta_to_a_copy_the_receiver_does_not_hold_is_refused_and_changes_nothing(tiny_world):
    team = _team(tiny_world, CodecConfig(bits=8, delta=True))
    team.round(RoundPlan.always(2))
    sender, receiver = team.members[0], team.members[1]
    message = sender.parameter_message(1, 1, 1)
    assert any(inst.params_code.base is not None for inst in message.instances)
    receiver.held_at[0] = {iid: 7 for iid in receiver.held_at[0]}  # as if it held other rounds' copies
    before = {iid: p.params.copy() for iid, p in receiver.held[0].items()}
    channel = Channel(2)
    with pytest.warns(UserWarning, match="a delta to its copy of round 0, this agent holds round 7"):
        delivery = channel.transmit(message, receiver.arrival_problem)
    assert delivery.status == "dropped" and delivery.message is None
    sender.acknowledge(1, "params", False, 1)
    assert all(np.array_equal(receiver.held[0][iid].params, v) for iid, v in before.items())


def test_a_coded_team_resumes_from_its_checkpoint_with_the_same_copies(tiny_world, tmp_path):
    codec = CodecConfig(bits=8, feature_bits=8, delta=True, keep=0.25, cloud_bits=16, lossless="zstd")
    team = _team(tiny_world, codec)
    for _ in range(2):
        team.round(RoundPlan.always(2))
    path = team.save(tmp_path / "team.pt")
    resumed = _team(tiny_world, codec)
    resumed.load(path)
    a, b = team.round(RoundPlan.always(2)), resumed.round(RoundPlan.always(2))
    assert a.bytes_sent == b.bytes_sent and a.delivered == b.delivered == 4  # deltas to the restored copies
    assert _copies_agree(resumed) > 0


def test_a_delta_of_another_bank_or_an_observed_change_off_the_copys_grid_is_refused(tiny_world):
    from mapping.model.observed import FREE, ObservedSpace

    team = _team(tiny_world, CodecConfig(bits=8, delta=True))
    team.round(RoundPlan.always(2))
    receiver = team.members[1]
    iid, copy = next(iter(receiver.held[0].items()))
    other = "structure" if copy.bank == "object" else "object"
    coded, _ = encode_vector(np.ones(7, np.float32), 8, 64, np.zeros(7, np.float32), receiver.held_at[0][iid])
    wrong = replace(copy, bank=other, params=decode_vector(coded), params_code=coded)
    assert "a delta of a" in receiver.arrival_problem(ParameterMessage(0, 1, 1, [wrong]))
    far = ObservedSpace.empty(copy.observed.cell_m if copy.observed is not None else 0.025)
    far.cover(np.full(3, 12.0), np.full(3, 12.1))
    far.mark(np.full((1, 3), 12.05), FREE)
    moved = replace(copy, observed=far, observed_code="delta")
    problem = receiver.arrival_problem(ParameterMessage(0, 1, 1, [moved]))
    assert problem is not None and ("does not hold this agent's copy" in problem or "holds none" in problem)


def test_the_env_runs_the_codec_in_every_action_form_and_passes_pettingzoos_test(warm_env_kwargs):
    """The codec is part of the episode's settings: the same spaces, and PettingZoo's parallel API test passes with
    coded, compressed messages over capacity-limited links in the instances form."""
    from pettingzoo.test import parallel_api_test

    from openmulti_env import parallel_env

    codec = dict(team__exchange__codec__bits=8, team__exchange__codec__delta=True, team__exchange__codec__keep=0.1,
                 team__exchange__codec__cloud_bits=16, team__exchange__codec__lossless="zstd")
    kwargs = warm_env_kwargs(preset="rl_tiny", num_agents=3, action_form="instances", instance_slots=4,
                             link_mb_per_round=0.05)
    coded, plain = parallel_env(**kwargs, **codec), parallel_env(**kwargs)
    for agent in coded.possible_agents:
        assert coded.observation_space(agent) == plain.observation_space(agent)
        assert coded.action_space(agent) == plain.action_space(agent)
    assert coded.config.team.exchange.codec.active and not plain.config.team.exchange.codec.active
    parallel_api_test(coded, num_cycles=4)
    for form in ("entries", "round"):
        env = parallel_env(**{**kwargs, "action_form": form}, **codec)
        env.reset(seed=1)
        _, _, _, _, infos = env.step({a: np.ones_like(env.action_space(a).sample()) for a in env.agents})
        assert all(info["messages_delivered"] >= 0 for info in infos.values())
        env.close()
