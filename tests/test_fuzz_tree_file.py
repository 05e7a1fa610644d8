"""Fuzzing the tree file loader: mutated files end in TreeFileError or a valid tree,
never another exception, a hang or a huge allocation.

`make test` runs a seeded sample; `make test-long` runs 10,000+ mutations."""
import hashlib

import numpy as np
import pytest

from kdray import layout
from kdray.errors import TreeFileError
from kdray.tree import KdTree
from small_trees import two_leaf_tree


def seed_files():
    files = [two_leaf_tree().to_bytes(),                        # version 1
             two_leaf_tree().with_objects(np.array([1, 0, 1]), ("a", "b")).to_bytes()]  # 3
    try:
        from kdray.builder import build
        rng = np.random.default_rng(5)
        tris = rng.random((60, 3, 3))
        files.append(build(tris.reshape(-1, 3), np.arange(180).reshape(60, 3)).to_bytes())
    except ImportError:
        pass
    return files


def mutate(data, rng):
    """One random mutation; half of them re-seal the checksum (a deliberately forged file)."""
    b = bytearray(data)
    kind = rng.integers(6)
    if kind == 0:                                   # flip bits
        for _ in range(rng.integers(1, 5)):
            b[rng.integers(len(b))] ^= 1 << int(rng.integers(8))
    elif kind == 1:                                 # truncate
        b = b[:rng.integers(len(b))]
    elif kind == 2:                                 # a header count or index set to something wild
        off = int(rng.choice([8, 12, 16, 20, 24, 28, 32, 36, 40, 44, 128, 132, 136, 140]))
        b[off:off + 4] = int(rng.choice([0, 1, 2**31, 2**32 - 1, rng.integers(2**32)])).to_bytes(4, "little")
    elif kind == 3:                                 # overwrite a node word
        n_nodes = int.from_bytes(b[16:20], "little")
        if n_nodes:
            i = layout.HEADER_SIZE + 4 * int(rng.integers(2 * min(n_nodes, 10**6)))
            if i + 4 <= len(b):
                b[i:i + 4] = int(rng.integers(2**32)).to_bytes(4, "little")
    elif kind == 4:                                 # a float made NaN / inf / huge
        i = int(rng.integers(48, max(49, len(b) - 20))) & ~3
        b[i:i + 4] = np.float32(rng.choice([np.nan, np.inf, -np.inf, 3e38])).tobytes()
    else:                                           # append junk
        b += bytes(rng.integers(256, size=rng.integers(1, 64)).astype(np.uint8))
    if rng.random() < 0.5 and len(b) > layout.CHECKSUM_SIZE:
        body = bytes(b[:-layout.CHECKSUM_SIZE])
        b = bytearray(body + hashlib.blake2b(body, digest_size=layout.CHECKSUM_SIZE).digest())
    return bytes(b)


def fuzz(n, seed):
    rng = np.random.default_rng(seed)
    refused = accepted = 0
    for data in seed_files():
        for _ in range(n):
            bad = mutate(data, rng)
            try:
                tree = KdTree.from_bytes(bad)
            except TreeFileError:
                refused += 1
                continue
            tree.validate(coverage_samples=None)     # an accepted file is a valid tree
            accepted += 1
    return refused, accepted


def test_fuzz_sample():
    refused, accepted = fuzz(600, seed=1)
    assert refused > 500


@pytest.mark.slow
def test_fuzz_long():
    refused, accepted = fuzz(6000, seed=2)
    assert refused > 5000
