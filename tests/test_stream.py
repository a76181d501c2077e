"""The DAQ stream format: CRC, frame layout, resynchronising decoder, block assembly."""
import struct

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from drivers.daq import BlockAssembler
from drivers.stream import (FLAG_END, FLAG_OVERLOAD, SYNC, FrameDecoder, Gap, StreamFormatError, crc32,
                            encode_end, encode_frame, frame_size)


def reference_crc32(data: bytes) -> int:
    """Bit-by-bit CRC-32/ISO-HDLC (reflected polynomial 0xEDB88320), independent of zlib."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0xEDB88320 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


def make_frames(rng, count, channels, max_points, start_sequence=0, start_sample=0):
    """(bytes, counts) of consecutive frames with random sizes and contents."""
    frames, sample = [], start_sample
    for k in range(count):
        points = int(rng.integers(1, max_points + 1))
        counts = rng.integers(-2**31, 2**31, size=(points, channels), dtype=np.int64).astype(np.int32)
        frames.append((encode_frame(start_sequence + k, sample, counts), counts))
        sample += points
    return frames, sample


def test_crc_is_crc32_iso_hdlc():
    assert crc32(b"123456789") == 0xCBF43926
    data = bytes(range(256)) * 3
    assert crc32(data) == reference_crc32(data)


def test_frame_layout_matches_the_documented_offsets():
    counts = np.array([[1, -2], [3, -4], [2**31 - 1, -2**31]], dtype=np.int32)
    frame = encode_frame(7, 1234567890123, counts, FLAG_OVERLOAD)
    assert len(frame) == frame_size(3, 2) == 20 + 4 * 3 * 2 + 4
    assert frame[:4] == bytes([0xA5, 0x5A, 0xC3, 0x3C])
    assert struct.unpack_from("<I", frame, 4)[0] == 7
    assert struct.unpack_from("<Q", frame, 8)[0] == 1234567890123
    assert struct.unpack_from("<HBB", frame, 16) == (3, 2, FLAG_OVERLOAD)
    assert struct.unpack_from("<6i", frame, 20) == (1, -2, 3, -4, 2**31 - 1, -2**31)
    assert struct.unpack_from("<I", frame, len(frame) - 4)[0] == reference_crc32(frame[:-4])


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), channels=st.integers(1, 5), max_points=st.integers(1, 40),
       cuts=st.lists(st.integers(1, 300), min_size=1, max_size=30))
def test_round_trip_in_any_chunking(seed, channels, max_points, cuts):
    rng = np.random.default_rng(seed)
    frames, total = make_frames(rng, 12, channels, max_points)
    stream = b"".join(f for f, _ in frames) + encode_end(12, total, channels) + b"0,\"No error\"\n"
    decoder = FrameDecoder(channels, max_points)
    decoded, position, k = [], 0, 0
    while position < len(stream):
        step = cuts[k % len(cuts)]
        decoded += decoder.feed(stream[position:position + step])
        position += step
        k += 1
    assert decoder.ended
    assert [f.sequence for f in decoded] == list(range(13))
    for frame, (_, counts) in zip(decoded, frames):
        np.testing.assert_array_equal(frame.counts, counts)
        assert frame.gap is None and frame.skipped_bytes == 0
    assert decoded[-1].is_end and decoded[-1].first_sample == total
    assert decoder.remainder() == b"0,\"No error\"\n"
    assert decoder.stats.samples == total and decoder.stats.lost_samples == 0


def test_a_view_of_the_data_kept_beyond_a_check_does_not_stop_the_next_feed(monkeypatch):
    """A Ctrl-C in a frame's check leaves that check's frame, and its view of the decoder's data, in the
    traceback; the decoder goes on decoding the frames that follow."""
    import drivers.stream

    rng = np.random.default_rng(3)
    frames, total = make_frames(rng, 4, 2, 5)
    views = []

    def checked(data):
        views.append(data)                                     # as a frame kept by a traceback keeps it
        return crc32(data)

    monkeypatch.setattr(drivers.stream, "crc32", checked)
    decoder = FrameDecoder(2, 5)
    decoded = decoder.feed(frames[0][0] + frames[1][0][:7])
    views.append(memoryview(decoder._buffer))                 # and one of what it holds between two feeds
    decoded += decoder.feed(frames[1][0][7:] + frames[2][0])
    decoded += decoder.feed(frames[3][0] + encode_end(4, total, 2))
    assert [f.sequence for f in decoded] == [0, 1, 2, 3, 4] and views


def test_every_single_bit_flip_is_detected_and_reported_as_a_gap():
    rng = np.random.default_rng(1)
    frames, total = make_frames(rng, 3, 2, 3)
    middle = frames[1][0]
    for bit in range(8 * len(middle)):
        damaged = bytearray(middle)
        damaged[bit // 8] ^= 1 << (bit % 8)
        decoder = FrameDecoder(2, 3)
        out = decoder.feed(frames[0][0] + bytes(damaged) + frames[2][0] + encode_end(3, total, 2))
        assert [f.sequence for f in out] == [0, 2, 3]
        np.testing.assert_array_equal(out[1].counts, frames[2][1])
        assert out[1].gap == Gap(1, 1, frames[0][1].shape[0], frames[1][1].shape[0])
        assert out[1].skipped_bytes == len(middle)
        assert decoder.stats.samples + decoder.stats.lost_samples == total


def test_garbage_fake_sync_words_and_truncation_are_skipped_and_counted():
    rng = np.random.default_rng(2)
    frames, total = make_frames(rng, 4, 3, 8)
    garbage = b"noise" + SYNC + b"\x00" * 7 + SYNC[:3]
    truncated = frames[2][0][: len(frames[2][0]) // 2]
    stream = garbage + frames[0][0] + frames[1][0] + truncated + SYNC + frames[3][0] + encode_end(4, total, 3)
    decoder = FrameDecoder(3, 8)
    out = decoder.feed(stream)
    assert [f.sequence for f in out] == [0, 1, 3, 4]
    assert out[0].skipped_bytes == len(garbage)
    assert out[2].skipped_bytes == len(truncated) + len(SYNC)
    assert out[2].gap.first_sequence == 2 and out[2].gap.frames == 1
    assert decoder.stats.samples + decoder.stats.lost_samples == total


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), p_drop=st.sampled_from([0.0, 1e-3, 1e-2]),
       p_flip=st.sampled_from([0.0, 1e-3, 1e-2]), p_insert=st.sampled_from([0.0, 1e-3]))
def test_random_damage_never_yields_a_wrong_sample_and_accounts_for_every_sample(seed, p_drop, p_flip, p_insert):
    rng = np.random.default_rng(seed)
    frames, total = make_frames(rng, 60, 2, 16)
    clean = b"".join(f for f, _ in frames)
    damaged = bytearray()
    for byte in clean:
        if rng.random() < p_insert:
            damaged += bytes(rng.integers(0, 256, 5, dtype=np.uint8))
        if rng.random() < p_drop:
            continue
        damaged.append(byte ^ (1 << int(rng.integers(8))) if rng.random() < p_flip else byte)
    decoder = FrameDecoder(2, 16)
    out = []
    for k in range(0, len(damaged), 97):
        out += decoder.feed(bytes(damaged[k:k + 97]))
    decoder.finish(total)
    for frame in out:
        np.testing.assert_array_equal(frame.counts, frames[frame.sequence][1])
    lost = sum(g.samples for g in decoder.stats.gaps)
    assert decoder.stats.samples + lost == total
    assert decoder.stats.lost_samples == lost


def test_finish_reports_the_trailing_loss_and_gap_text_names_the_frames():
    rng = np.random.default_rng(3)
    frames, total = make_frames(rng, 5, 1, 4)
    decoder = FrameDecoder(1, 4)
    decoder.feed(b"".join(f for f, _ in frames[:3]))
    gap = decoder.finish(total)
    tail = sum(c.shape[0] for _, c in frames[3:])
    assert gap == Gap(3, 0, total - tail, tail)
    delivered = sum(c.shape[0] for _, c in frames[:3])
    assert decoder.stats.samples == delivered and decoder.stats.lost_samples == tail
    text = str(Gap(17, 2, 4352, 512))
    assert "frames 17..18" in text and "4352..4863" in text


def test_a_frame_going_back_in_time_is_a_format_error():
    counts = np.zeros((4, 1), dtype=np.int32)
    decoder = FrameDecoder(1, 4)
    decoder.feed(encode_frame(0, 0, counts) + encode_frame(1, 4, counts))
    with pytest.raises(StreamFormatError):
        decoder.feed(encode_frame(2, 2, counts))


def test_header_with_wrong_channel_count_or_flags_is_not_a_frame():
    counts = np.ones((2, 2), dtype=np.int32)
    decoder = FrameDecoder(3, 8)
    assert decoder.feed(encode_frame(0, 0, counts)) == []
    decoder = FrameDecoder(2, 8)
    bad_flags = bytearray(encode_frame(0, 0, counts, 0))
    bad_flags[19] = FLAG_END  # an END flag on a frame with samples
    assert decoder.feed(bytes(bad_flags)) == []


def test_blocks_are_contiguous_split_at_gaps_and_scaled():
    rng = np.random.default_rng(4)
    frames, total = make_frames(rng, 10, 2, 7)
    kept = [f for k, f in enumerate(frames) if k not in (4, 5)]
    decoder = FrameDecoder(2, 7)
    decoded = decoder.feed(b"".join(f for f, _ in kept) + encode_end(10, total, 2))
    lsb = np.array([0.5, 2.0])
    assembler = BlockAssembler(6, lsb, ("a", "b"), ("N", "m/s^2"), 100.0)
    blocks = [b for frame in decoded for b in assembler.add(frame)]
    tail = assembler.flush()
    blocks += [tail] if tail is not None else []
    truth = np.concatenate([c for _, c in frames]) * lsb
    lost = decoder.stats.gaps[0]
    for block in blocks:
        np.testing.assert_array_equal(block.data, truth[block.first_sample:block.first_sample + len(block)])
        assert not (block.first_sample < lost.first_sample + lost.samples
                    and block.first_sample + len(block) > lost.first_sample)
    assert [b.gaps for b in blocks].count((lost,)) == 1
    assert sum(len(b) for b in blocks) + lost.samples == total
    short = [b for b in blocks if len(b) < 6]
    assert all(b is tail or b.first_sample + len(b) == lost.first_sample for b in short)
