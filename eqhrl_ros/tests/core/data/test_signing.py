"""The shared key (core/data/signing.py): forgeries, altered content, moved senders and replays refused."""

import os

import pytest

from eqhrl_ros.core.data.signing import (
    CommandCheck,
    CommandSeal,
    KeyFileError,
    RequestCheck,
    RequestSeal,
    Signer,
    from_exact_floats,
    key_readable_by_others,
    new_key_file,
    read_key,
    signer_from,
    to_exact_floats,
)

KEY = b'k' * 32


def test_a_signature_covers_kind_sender_sequence_and_content():
    signer = Signer(KEY)
    sig = signer.sign('weights', 'trainer-1', 7, [b'abc', b'def'])
    assert signer.verify(sig, 'weights', 'trainer-1', 7, [b'abc', b'def'])
    assert not Signer(b'x' * 32).verify(sig, 'weights', 'trainer-1', 7, [b'abc', b'def'])  # another key
    assert not signer.verify(sig, 'weights', 'trainer-2', 7, [b'abc', b'def'])  # moved to another sender
    assert not signer.verify(sig, 'weights', 'trainer-1', 8, [b'abc', b'def'])  # another sequence number
    assert not signer.verify(sig, 'transitions', 'trainer-1', 7, [b'abc', b'def'])  # another kind
    assert not signer.verify(sig, 'weights', 'trainer-1', 7, [b'abcd', b'ef'])  # the same bytes split otherwise
    assert not signer.verify(sig[:-1] + bytes([sig[-1] ^ 1]), 'weights', 'trainer-1', 7, [b'abc', b'def'])
    assert not signer.verify(b'', 'weights', 'trainer-1', 7, [b'abc', b'def'])


def test_key_files_are_checked_and_made_private(tmp_path):
    path = new_key_file(tmp_path / 'deployment.key')
    assert len(read_key(path)) == 64 and not key_readable_by_others(path)
    (tmp_path / 'short.key').write_text('secret\n')
    with pytest.raises(KeyFileError, match='at least 16'):
        read_key(tmp_path / 'short.key')
    with pytest.raises(KeyFileError, match='cannot be read'):
        read_key(tmp_path / 'missing.key')
    os.chmod(path, 0o644)
    assert key_readable_by_others(path)


def test_signatures_travel_exactly_as_float32_values():
    sig = Signer(KEY).sign('command', '', 1, [b'x'])
    values = to_exact_floats(sig)
    assert len(values) == 16 and from_exact_floats(values) == sig
    assert from_exact_floats([0.5] * 16) == b''


def test_a_sealed_command_is_taken_once_and_a_replay_or_a_forgery_is_not():
    now = [1_800_000_000.0]
    seal, check = CommandSeal(Signer(KEY), lambda: now[0]), CommandCheck(Signer(KEY), lambda: now[0])
    values = [0.5, 1.0, 0.0, 0.0]
    counter, signature = seal.seal(values)
    assert check.refusal(values, counter, signature) == ''
    assert 'replay' in check.refusal(values, counter, signature)
    counter2, signature2 = seal.seal(values)  # the same millisecond: the counter still rises
    assert counter2 != counter and check.refusal(values, counter2, signature2) == ''
    c3, s3 = seal.seal(values)
    assert 'signature' in check.refusal([-1.0, 1.0, 0.0, 0.0], c3, s3)  # the value changed on the way
    forged_counter, forged = CommandSeal(Signer(b'z' * 32), lambda: now[0]).seal(values)
    assert 'signature' in check.refusal(values, forged_counter, forged)
    assert 'unsigned' in check.refusal(values, None, None)
    late = CommandSeal(Signer(KEY), lambda: now[0] - 60.0)
    c4, s4 = late.seal(values)
    fresh = CommandCheck(Signer(KEY), lambda: now[0])
    assert 's from this machine' in fresh.refusal(values, c4, s4)


def test_a_signed_request_is_answered_once_and_its_answer_is_taken_for_it_alone():
    """The Advise service with a key: a stranger can neither ask (no signature, another key, an
    altered or replayed request) nor answer (an unsigned answer, another key, an altered answer,
    or the key holder's answer to another request passed off as this one's)."""
    now = [1_800_000_000.0]
    seal, check = (
        RequestSeal(Signer(KEY), 'advise', lambda: now[0]),
        RequestCheck(Signer(KEY), 'advise', lambda: now[0]),
    )
    parts = [b'observation', b'action']
    counter, signature = seal.seal(parts)
    assert check.refusal(counter, parts, signature) == ''
    assert 'replay' in check.refusal(counter, parts, signature)  # anyone on the graph reads the requests
    c2, s2 = seal.seal(parts)  # the same content, the same millisecond: another request
    assert c2 == counter + 1 and check.refusal(c2, parts, s2) == ''
    c3, s3 = seal.seal(parts)
    assert 'signature' in check.refusal(c3, [b'observation', b'other action'], s3)
    assert 'signature' in check.refusal(
        c3, parts, RequestSeal(Signer(b'z' * 32), 'advise', lambda: now[0]).seal(parts)[1]
    )
    assert 'signature' in check.refusal(c3, parts, Signer(KEY).sign('command', '', c3, parts))  # another kind
    assert (
        check.refusal(0, parts, b'') == check.refusal(c3, parts, b'') == 'it is unsigned and this node has a key_file'
    )
    now[0] += 31.0  # a request kept back and sent later
    assert 's from this machine' in check.refusal(c3, parts, s3)

    answer = [b'advised', b'action']
    signed = check.seal_answer(counter, signature, answer)
    assert seal.answer_refusal(counter, signature, answer, signed) == ''
    assert 'unsigned' in seal.answer_refusal(counter, signature, answer, b'')
    assert 'signature' in seal.answer_refusal(counter, signature, [b'advised', b'another action'], signed)
    assert 'signature' in seal.answer_refusal(c2, s2, answer, signed)  # an earlier answer for a later request
    other = RequestCheck(Signer(b'z' * 32), 'advise', lambda: now[0]).seal_answer(counter, signature, answer)
    assert 'signature' in seal.answer_refusal(counter, signature, answer, other)
    # Seen requests are kept only for the window in which they could pass the time check.
    now[0] += 60.0
    c4, s4 = seal.seal(parts)
    assert check.refusal(c4, parts, s4) == '' and len(check._seen) == 1


def test_a_key_file_that_other_users_may_read_is_said_when_a_node_reads_it(tmp_path):
    path = new_key_file(tmp_path / 'deployment.key')
    said = []
    assert signer_from(str(path), said.append) is not None and said == []
    os.chmod(path, 0o640)  # the group may read it
    assert signer_from(str(path), said.append) is not None
    assert len(said) == 1 and 'readable by other users' in said[0] and said[0].endswith(f'chmod 600 {path}')
    assert signer_from('', said.append) is None and len(said) == 1
