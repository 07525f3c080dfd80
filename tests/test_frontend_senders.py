"""Two senders on one CAN id (issue 12, finding 8) and SampleIdx jumps by reason.

E2E profile 1 cannot reject a masquerader with a valid CRC; the validator notices the two
interleaved alive-counter/SampleIdx sequences, counts them, flags the message and the
front end excludes it from the grid until it is single again.
"""

from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.can.codec import default_codec
from gateway.can.e2e import COUNTER_MODULUS, SenderCheck, SenderParams
from gateway.config import Config
from gateway.frontend.chain import FrontEnd

P = SenderParams()


def _seq(n: int, idx0: int, counter0: int = 0) -> list[tuple[int, int]]:
    return [((counter0 + i) % COUNTER_MODULUS, (idx0 + i) % 65536) for i in range(n)]


def test_one_sender_with_loss_reorder_and_wrap_is_single():
    frames = _seq(3000, 65000)
    del frames[100:105]                              # lost frames
    frames[200], frames[201] = frames[201], frames[200]  # overtaken by one
    check = SenderCheck()
    for c, i in frames:
        check.feed(c, i)
    assert not check.state.two_senders and check.state.events == 0
    assert check.state.jumps == {"idx_jump": 0, "idx_back": 0, "idx_repeat": 0}


def test_a_node_restart_counts_one_jump_and_no_second_sender():
    check = SenderCheck()
    for c, i in _seq(500, 100) + _seq(2000, 20_000, counter0=7):
        check.feed(c, i)
    assert check.state.jumps["idx_jump"] == 1
    assert not check.state.two_senders and check.state.events == 0


def test_sample_index_jumps_are_counted_by_reason():
    check = SenderCheck()
    frames = _seq(50, 1000)
    c, last = frames[-1]
    frames += [(c + 1, 990)]                         # backwards
    frames += [(c + 2, last)]                        # the newest index again
    frames += [(c + 3, 30_000)]                      # far forward
    for c, i in frames:
        check.feed(c % COUNTER_MODULUS, i)
    assert check.state.jumps == {"idx_jump": 1, "idx_back": 1, "idx_repeat": 1}


def test_interleaved_senders_raise_then_clear_with_hysteresis():
    a, b = _seq(5000, 0), _seq(2000, 20_000, counter0=5)
    check = SenderCheck()
    raised_at = cleared_at = None
    # a alone, then a and b interleaved, then a alone again
    stream = a[:1000] + [x for pair in zip(a[1000:3000], b, strict=True) for x in pair] \
        + a[3000:]
    for n, (c, i) in enumerate(stream):
        check.feed(c, i)
        if check.state.two_senders and raised_at is None:
            raised_at = n
        if raised_at is not None and not check.state.two_senders and cleared_at is None:
            cleared_at = n
    assert raised_at is not None and 1000 <= raised_at <= 1000 + 2 * P.block_frames
    assert cleared_at is not None
    hold = P.clear_blocks * P.block_frames
    assert 5000 + hold - P.block_frames <= cleared_at <= 5000 + hold + P.block_frames
    assert check.state.events == 1 and check.state.second_frames > 1900


def test_same_index_masquerader_is_still_two_senders():
    a, b = _seq(2000, 500), _seq(2000, 500, counter0=9)  # same SampleIdx, own counter
    check = SenderCheck()
    for pair in zip(a, b, strict=True):
        for c, i in pair:
            check.feed(c, i)
    assert check.state.two_senders


@pytest.mark.parametrize("idx_offset", [20_000, 3])
def test_front_end_excludes_the_doubled_stream_and_takes_it_back(idx_offset):
    # the second BGN sends from 2 s to 4 s with values x 1.5 and its own SampleIdx (far
    # from the real one, or 3 samples ahead: inside the clock model's tolerance)
    sim = Simulation(get_scenario("nominal"), SimConfig(
        duration_s=7.0, seed=3, second_sender="BGN", second_sender_window_s=(2.0, 4.0),
        second_sender_idx_offset=idx_offset))
    fe = FrontEnd(Config(), default_codec())
    out = []
    for n, m in enumerate(sim.messages()):
        out.extend(fe.on_frame(m))
        if n % 1000 == 0:
            out.extend(fe.on_time(m.timestamp))
    out.extend(fe.finish())
    st = fe.stats()
    assert st.two_sender_events["BGN_Lat"] == 1 and st.two_senders == ()
    assert st.rejected["two_senders"] > 3500        # both senders, 2 s x 2 kHz, less
    # cleared after clear_blocks x block_frames single frames (1 kHz), block-aligned
    hold_s = (SenderParams().clear_blocks + 1) * SenderParams().block_frames / 1000
    assert 2000 <= st.gaps["BGN_Lat"]["excluded"] <= 2000 + 1000 * (hold_s + 1.0)
    t = np.array([s.t_s for s in out])
    acc_b = np.array([s.values[0] for s in out])   # 3-sensor set: acc_b, gyro_b, acc_bd
    inside = (t > 2.1) & (t < 3.9)
    assert np.all(np.isnan(acc_b[inside]))          # excluded while doubled
    before, after = (t > 0.5) & (t < 1.9), (t > 4.0 + hold_s + 0.2) & (t < 6.9)
    assert np.all(np.isfinite(acc_b[after]))        # back, single again
    # and it is the genuine node's signal, not the x 1.5 one
    assert 0.8 < np.std(acc_b[after]) / np.std(acc_b[before]) < 1.25


@pytest.mark.parametrize(("heard", "lost"), [(10, 20), (3, 17), (1, 17), (5, 40), (20, 100),
                                             (60, 200)])
def test_one_sender_losing_frames_in_bursts_is_single(heard, lost):
    # a node heard for `heard` frames, then `lost` frames dropped (a full kernel buffer or
    # queue under load: more than max_step, so each resumption is an index jump), again
    # and again: one sender, never two (2026-11-26: the systemd check's guest flagged BDN,
    # BGN and WSN when its service fell behind)
    frames = [f for k, f in enumerate(_seq(20_000, 60_000)) if k % (heard + lost) < heard]
    check = SenderCheck()
    for c, i in frames:
        check.feed(c, i)
    assert lost > P.max_step and check.state.jumps["idx_jump"] > 50
    assert not check.state.two_senders and check.state.events == 0


@pytest.mark.parametrize("burst", [1, 2, 4, 8])
@pytest.mark.parametrize("offset", [3, 30, 20_000, -20_000])
def test_two_senders_taking_turns_in_bursts_are_two(burst, offset):
    # the masquerader's sequence ahead of or behind the node's, each sending `burst`
    # frames in turn (on a real bus two 1 kHz senders interleave frame by frame)
    a, b = _seq(4000, 1000), _seq(4000, (1000 + offset) % 65536, counter0=5)
    check = SenderCheck()
    raised_at = None
    stream = [f for j in range(0, 4000, burst) for f in a[j:j + burst] + b[j:j + burst]]
    for n, (c, i) in enumerate(stream):
        check.feed(c, i)
        if check.state.two_senders and raised_at is None:
            raised_at = n
    assert raised_at is not None and raised_at < 2 * P.block_frames


def test_front_end_keeps_every_node_when_frames_are_lost_in_bursts():
    # 2026-11-26: at the traffic's start in the systemd check's guest the kernel dropped
    # 79-1,006 frames from the full socket buffer, and BDN, BGN and WSN were flagged as
    # two senders and excluded. Here every node loses 20 frames (20 ms) out of every 32,
    # all at the same moments, as a stalled reader loses them
    sim = Simulation(get_scenario("nominal"), SimConfig(duration_s=4.0, seed=3))
    fe = FrontEnd(Config(), default_codec())
    out, kept, t0 = [], 0, None
    for n, m in enumerate(sim.messages()):
        t0 = m.timestamp if t0 is None else t0
        if (m.timestamp - t0) % 0.032 < 0.020:
            continue                                  # lost in the burst
        kept += 1
        out.extend(fe.on_frame(m))
        if n % 1000 == 0:
            out.extend(fe.on_time(m.timestamp))
    out.extend(fe.finish())
    st = fe.stats()
    assert st.two_senders == () and not any(st.two_sender_events.values())
    assert st.rejected.get("two_senders", 0) == 0
    lateral = ("BGN_Lat", "BDN_Lat", "WSN_Lat")
    assert sum(st.sample_idx_jumps[name]["idx_jump"] for name in lateral) > 100
    assert all(st.gaps[name].get("excluded", 0) == 0 for name in st.gaps)
    values = np.array([s.values for s in out])     # 12 of every 32 ms heard: 37.5 %
    assert kept > 4000 and np.isfinite(values).all(axis=1).mean() > 0.3


@pytest.mark.parametrize("lost_ms", [13, 14, 15, 16, 29, 30, 45])
def test_bursts_of_lost_frames_are_lost_not_repeated_or_reordered(lost_ms):
    # 2026-11-26: in the VM, with the CAN socket's 4 MiB buffer the service fell behind
    # and the kernel dropped frames in bursts; 28 good frames were rejected as repeats.
    # A loss of 15k frames leaves the 4-bit alive counter where it was (a "repeat") and
    # one of 15k - 1 one behind (a "reordered" frame, after which the next is a
    # "repeat"). The sample index tells them apart: every frame after a burst is
    # accepted, and each message's lost frames are exactly those removed.
    sim = Simulation(get_scenario("nominal"), SimConfig(duration_s=2.0, seed=3))
    fe = FrontEnd(Config(), default_codec())
    removed: dict[int, int] = {}
    t0 = None
    for m in sim.messages():
        t0 = m.timestamp if t0 is None else t0
        if 0.05 < (m.timestamp - t0) % 0.1 < 0.05 + lost_ms / 1000 and m.timestamp - t0 < 1.9:
            removed[m.arbitration_id] = removed.get(m.arbitration_id, 0) + 1
            continue
        fe.on_frame(m)
    fe.finish()
    assert fe.stats().rejected == {}
    codec = default_codec()
    for name, st in fe.validator.messages.items():
        fid = codec.message(name).frame_id
        assert st.lost_frames == removed.get(fid, 0), (name, st.lost_frames, removed.get(fid))
        assert st.reordered == 0, name


def test_a_repeated_frame_is_still_rejected_after_a_loss():
    # the sample index decides only a step forward: a frame sent twice after a burst of
    # lost frames is still a repeat
    sim = Simulation(get_scenario("nominal"), SimConfig(duration_s=0.5, seed=3))
    fe = FrontEnd(Config(), default_codec())
    bgn = default_codec().message("BGN_Lat").frame_id
    seen = 0
    for m in sim.messages():
        if m.arbitration_id == bgn:
            seen += 1
            if 100 <= seen < 115:                    # 15 BGN frames lost
                continue
            fe.on_frame(m)
            if seen == 115:
                fe.on_frame(m)                       # the frame after the burst, twice
            continue
        fe.on_frame(m)
    fe.finish()
    assert fe.stats().rejected == {"counter_repeated": 1}
    assert fe.validator.messages["BGN_Lat"].lost_frames == 15


def test_every_required_message_excluded_leaves_the_grid_on_the_deadline():
    # two senders on every lateral id at once (a rogue device copying all the nodes):
    # with nothing left to wait for, the grid used to finalise points without end on
    # the next frame (the process ran out of memory); it must follow the deadline
    sim = Simulation(get_scenario("nominal"), SimConfig(duration_s=3.0, seed=3))
    fe = FrontEnd(Config(), default_codec())
    messages = list(sim.messages())
    finalize, points = fe.resampler._finalize, [0]

    def bounded(j: int) -> None:                     # a regression fails, not OOMs, CI
        points[0] += 1
        if points[0] > 100_000:
            raise AssertionError("the grid ran away: 100,000 points for 3 s of data")
        finalize(j)

    fe.resampler._finalize = bounded
    out = []
    for n, m in enumerate(messages):
        if n == len(messages) // 3:
            for name in fe.resampler.config.required_messages:
                fe.resampler.set_excluded(name, True)
        out.extend(fe.on_frame(m))
        if n % 500 == 0:
            out.extend(fe.on_time(m.timestamp))
    t_last = messages[-1].timestamp
    t = np.array([s.t_s for s in out])
    assert len(t) > 0 and np.all(np.diff(t) > 0)
    assert t[-1] <= t_last + 0.01                    # not run ahead of the data
    values = np.array([s.values for s in out])
    late = t > messages[len(messages) // 3].timestamp + 0.5
    assert late.sum() > 1000 and np.all(np.isnan(values[late]))   # excluded: MISSING
