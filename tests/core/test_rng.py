"""The compiled refill of the random streams draws exactly what NumPy's Generator methods draw."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

from containergym_marl.core import BLOCK_ROWS, NoiseStreams

N = 11


def _numpy_blocks(generator: np.random.Generator, blocks: int, n: int = N) -> tuple[np.ndarray, np.ndarray]:
    """``blocks`` blocks as the stream is defined: standard_normal((BLOCK_ROWS, n)) then
    random((BLOCK_ROWS, n)), drawn by NumPy itself."""
    drawn = [(generator.standard_normal((BLOCK_ROWS, n)), generator.random((BLOCK_ROWS, n))) for _ in range(blocks)]
    return np.concatenate([d[0] for d in drawn]), np.concatenate([d[1] for d in drawn])


def _stream_rows(streams: NoiseStreams, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """(steps, B, n) normals and uniforms of ``steps`` events of every simulation."""
    rows = [streams.next_rows() for _ in range(steps)]
    return np.stack([r[0] for r in rows]), np.stack([r[1] for r in rows])


def _bit_generator(kind: str, seed: int) -> np.random.Generator:
    return np.random.Generator(getattr(np.random, kind)(seed))


@pytest.mark.parametrize("kind", ["PCG64", "MT19937", "Philox"])
def test_a_batch_draws_numpys_numbers_and_leaves_numpys_state(kind):
    """64 simulations × 4 blocks × 11 containers: 22,528 normals, enough to pass through the
    ziggurat's wedges (~1 in 100) and its tail (~1 in 700) many times. Each bit generator has its own
    next_double (MT19937's is built from two 32-bit draws), so every kind must match NumPy's."""
    sims = 64
    streams = NoiseStreams([_bit_generator(kind, s) for s in range(sims)], N)
    assert streams._bitgen is not None  # one kind of bit generator: the compiled refill
    normals, uniforms = _stream_rows(streams, 4 * BLOCK_ROWS)
    for b in range(sims):
        reference = _bit_generator(kind, b)
        want_normals, want_uniforms = _numpy_blocks(reference, 4)
        np.testing.assert_array_equal(normals[:, b], want_normals)
        np.testing.assert_array_equal(uniforms[:, b], want_uniforms)
        # the generator itself advanced exactly as NumPy's calls advance it
        np.testing.assert_equal(streams.generator(b).bit_generator.state, reference.bit_generator.state)


def test_mixed_bit_generators_fall_back_to_numpys_calls_with_the_same_numbers():
    generators = [_bit_generator("PCG64", 5), _bit_generator("MT19937", 6)]
    streams = NoiseStreams(generators, N)
    assert streams._bitgen is None
    normals, uniforms = _stream_rows(streams, BLOCK_ROWS + 1)
    for b, (kind, seed) in enumerate([("PCG64", 5), ("MT19937", 6)]):
        want_normals, want_uniforms = _numpy_blocks(_bit_generator(kind, seed), 2)
        np.testing.assert_array_equal(normals[:, b], want_normals[:BLOCK_ROWS + 1])
        np.testing.assert_array_equal(uniforms[:, b], want_uniforms[:BLOCK_ROWS + 1])


def test_a_replaced_generator_of_another_kind_switches_to_the_fallback_and_back():
    streams = NoiseStreams([_bit_generator("PCG64", s) for s in range(3)], N)
    streams.set_generator(1, _bit_generator("MT19937", 7))
    assert streams._bitgen is None
    normals, _ = _stream_rows(streams, 1)
    np.testing.assert_array_equal(normals[0, 1], _bit_generator("MT19937", 7).standard_normal((BLOCK_ROWS, N))[0])
    streams.set_generator(1, _bit_generator("PCG64", 8))
    assert streams._bitgen is not None
    normals, _ = _stream_rows(streams, 1)
    np.testing.assert_array_equal(normals[0, 1], np.random.default_rng(8).standard_normal((BLOCK_ROWS, N))[0])


def test_draws_from_the_generator_between_refills_are_seen_as_with_numpy():
    """The simulator draws from the generator object it was given, not from a copy of its state:
    whoever else draws from that generator moves the stream, as it did with NumPy's own calls."""
    generator = np.random.default_rng(3)
    streams = NoiseStreams([generator], N)
    _stream_rows(streams, BLOCK_ROWS)
    generator.random(5)
    normals, _ = _stream_rows(streams, 1)
    reference = np.random.default_rng(3)
    _numpy_blocks(reference, 1)
    reference.random(5)
    np.testing.assert_array_equal(normals[0, 0], reference.standard_normal((BLOCK_ROWS, N))[0])


@pytest.mark.parametrize("duplicate", [copy.deepcopy, lambda s: pickle.loads(pickle.dumps(s))])
def test_a_copy_draws_from_its_own_generators(duplicate):
    """A copy (deepcopy, or a pickle sent to another process) must draw from its own generators:
    it holds their addresses, never the original's."""
    streams = NoiseStreams([np.random.default_rng(s) for s in range(4)], N)
    _stream_rows(streams, 3)
    twin = duplicate(streams)
    copied, _ = _stream_rows(twin, 2 * BLOCK_ROWS)
    original, _ = _stream_rows(streams, 2 * BLOCK_ROWS)
    np.testing.assert_array_equal(copied, original)
    for b in range(4):
        assert twin.generator(b) is not streams.generator(b)
        assert twin.generator(b).bit_generator.state == streams.generator(b).bit_generator.state
