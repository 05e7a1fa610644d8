"""Tree file format: golden bytes, round trip, and refusal of corrupt files."""
from pathlib import Path

import numpy as np
import pytest

from kdray import layout
from kdray.errors import TreeFileError
from kdray.tree import KdTree
from small_trees import two_leaf_tree

GOLDEN = Path(__file__).parent / "data" / "tree_v1.bin"


def test_node_encoding_round_trip():
    nodes = np.concatenate([layout.make_interior([0, 1, 2], [1.5, -0.0, 3e38], [5, 7, 1 << 29]),
                            layout.make_leaf([0, 12, (1 << 30) - 1], [0, 99, 2**32 - 1])])
    assert list(layout.split_axis(nodes)) == [0, 1, 2, 3, 3, 3]
    assert list(layout.above_child(nodes[:3])) == [5, 7, 1 << 29]
    assert list(layout.split(nodes[:3])) == [1.5, 0.0, np.float32(3e38)]
    assert np.signbit(layout.split(nodes[1:2]))[0]
    assert list(layout.n_prims(nodes[3:])) == [0, 12, (1 << 30) - 1]
    assert list(layout.leaf_offset(nodes[3:])) == [0, 99, 2**32 - 1]


def test_golden_bytes_guard_the_format():
    assert two_leaf_tree().to_bytes() == GOLDEN.read_bytes()
    assert KdTree.load(GOLDEN) == two_leaf_tree()


def test_round_trip(tmp_path):
    tree = two_leaf_tree()
    path = tmp_path / "t.bin"
    tree.save(path)
    back = KdTree.load(path)
    assert back == tree
    assert back.origin.dtype == np.float64 and back.origin[0] == 1e6


def test_header_layout_is_documented():
    data = GOLDEN.read_bytes()
    assert data[:8] == b"KDRAYTRE"
    assert int.from_bytes(data[8:12], "little") == 1            # scale 1: version 1
    assert len(data) == layout.file_size(3, 2, 2)
    assert np.frombuffer(data, "<f8", 3, 72).tolist() == [1e6, -2.5, 0.125]
    assert data[120:128] == bytes(8)                            # reserved in version 1


def test_scaled_tree_is_version_2(tmp_path):
    """A tree whose scale is not 1 is written as version 2, the scale at byte 120;
    the rest of the file is version 1's. Both read back; a scale that is not a power
    of two, and an unknown version, are refused."""
    import dataclasses
    tree = dataclasses.replace(two_leaf_tree(), scale=2.0 ** -70)
    data = tree.to_bytes()
    assert int.from_bytes(data[8:12], "little") == 2 == layout.VERSION
    assert np.frombuffer(data, "<f8", 1, 120)[0] == 2.0 ** -70
    one = two_leaf_tree().to_bytes()
    assert data[12:120] == one[12:120] and data[128:-16] == one[128:-16]
    path = tmp_path / "t.bin"
    tree.save(path)
    back = KdTree.load(path)
    assert back == tree and back.scale == 2.0 ** -70
    assert KdTree.from_bytes(one).scale == 1.0

    def resealed(data, offset, value):
        import hashlib
        bad = bytearray(data)
        bad[offset:offset + len(value)] = value
        body = bytes(bad[:-16])
        return body + hashlib.blake2b(body, digest_size=16).digest()
    for scale in (3.0, 0.0, -2.0, float("inf"), float("nan"), 2.0 ** 200):
        with pytest.raises(TreeFileError, match="scale"):
            KdTree.from_bytes(resealed(data, 120, np.float64(scale).tobytes()))
    with pytest.raises(TreeFileError, match="version 3"):
        KdTree.from_bytes(resealed(data, 8, (3).to_bytes(4, "little")))


@pytest.mark.parametrize("cut", [0, 7, 127, 128, 150, -17, -1])
def test_truncated_file_is_refused(tmp_path, cut):
    data = GOLDEN.read_bytes()
    path = tmp_path / "t.bin"
    path.write_bytes(data[:cut] if cut >= 0 else data[:len(data) + cut])
    with pytest.raises(TreeFileError):
        KdTree.load(path)


def test_every_flipped_byte_is_refused():
    data = GOLDEN.read_bytes()
    for i in range(len(data)):
        bad = bytearray(data)
        bad[i] ^= 0x5A
        with pytest.raises(TreeFileError):
            KdTree.from_bytes(bytes(bad))


def test_other_version_and_magic(tmp_path):
    data = bytearray(GOLDEN.read_bytes())
    data[8] = 3
    with pytest.raises(TreeFileError, match="version 3"):
        KdTree.from_bytes(bytes(data))
    with pytest.raises(TreeFileError, match="not a kdray tree"):
        KdTree.from_bytes(b"PLY\n" + bytes(200))


def _resealed(tree_bytes_editor):
    """Bytes of the golden tree after an edit, with a valid checksum (a hostile file)."""
    import hashlib
    body = bytearray(GOLDEN.read_bytes()[:-layout.CHECKSUM_SIZE])
    tree_bytes_editor(body)
    return bytes(body) + hashlib.blake2b(bytes(body), digest_size=layout.CHECKSUM_SIZE).digest()


def test_hostile_counts_and_indices_are_refused():
    def huge_count(b):
        b[16:20] = (2**31).to_bytes(4, "little")
    def child_out_of_range(b):
        b[128:132] = (3 | (50 << 2)).to_bytes(4, "little")  # above_child = 50... as leaf? no: axis 3
        b[128:132] = (0 | (50 << 2)).to_bytes(4, "little")
    def child_cycle(b):
        b[128:132] = (0 | (0 << 2)).to_bytes(4, "little")
    def leaf_range(b):
        b[136:140] = (3 | (9 << 2)).to_bytes(4, "little")
    def tri_id_range(b):
        b[-8:-4] = (7).to_bytes(4, "little")
    def nan_split(b):
        b[132:136] = np.float32(np.nan).tobytes()
    for edit in (huge_count, child_out_of_range, child_cycle, leaf_range, tri_id_range, nan_split):
        with pytest.raises(TreeFileError):
            KdTree.from_bytes(_resealed(edit))
