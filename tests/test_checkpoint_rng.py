"""A restored RBPF draws exactly what the uninterrupted one draws, Halton prior included.

scipy's QMC engines seed themselves by spawning from the Generator's SeedSequence, so a
checkpoint that kept only the bit-generator state made every later prior draw (a baseline
reset's redraw, a reseed) come from fresh OS entropy after a restart: not reproducible.
"""

from __future__ import annotations

import json

import numpy as np

from gateway.estimator import checkpoint as ckpt
from gateway.estimator.rbpf import RBPF, RBPFConfig
from gateway.records import Sample


def test_generator_state_round_trip_keeps_the_seed_sequence():
    rng = np.random.default_rng(5)
    rng.random()
    back = ckpt.generator_from_state(json.loads(json.dumps(ckpt.generator_state(rng))))
    a, b = rng.bit_generator.seed_seq, back.bit_generator.seed_seq
    assert (a.entropy, a.spawn_key, a.n_children_spawned) == \
        (b.entropy, b.spawn_key, b.n_children_spawned)
    assert np.array_equal(a.spawn(1)[0].generate_state(4), b.spawn(1)[0].generate_state(4))
    assert rng.random() == back.random()


def test_a_restored_rbpf_redraws_a_parameter_as_the_uninterrupted_one():
    rbpf = RBPF(RBPFConfig(fs_hz=1000.0, n_particles=16, sensors=3, seed=7))
    rng = np.random.default_rng(3)
    samples = [Sample(k * 1e-3, rng.normal(0.0, 0.1, 3), 40.0, True) for k in range(20)]
    for s in samples:
        rbpf.step(s)
    copy = RBPF.restore(rbpf.checkpoint())
    rbpf.reset_parameter(1)                     # a baseline reset redraws from the prior
    copy.reset_parameter(1)
    assert np.array_equal(rbpf.z, copy.z)
    assert copy.checkpoint() == rbpf.checkpoint()
