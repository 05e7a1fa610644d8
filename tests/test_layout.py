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
    assert int.from_bytes(data[8:12], "little") == 2
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
    with pytest.raises(TreeFileError, match="version 4"):
        KdTree.from_bytes(resealed(data, 8, (4).to_bytes(4, "little")))


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
    data[8] = 4
    with pytest.raises(TreeFileError, match="version 4"):
        KdTree.from_bytes(bytes(data))
    with pytest.raises(TreeFileError, match="not a kdray tree"):
        KdTree.from_bytes(b"PLY\n" + bytes(200))


def feed_pipe(path, data, hold):
    """A FIFO made at path; a thread writes `data` into it, then keeps it open until
    the event `hold` is set (or 60 s), as a pipe whose writer has not finished."""
    import os
    import threading

    os.mkfifo(path)

    def write():
        with open(path, "wb") as f:
            f.write(data)
            f.flush()
            hold.wait(60)
    writer = threading.Thread(target=write, daemon=True)
    writer.start()
    return writer


def test_tree_files_from_pipes(tmp_path):
    """A tree file through a pipe loads as the file does (its size is what its header
    says, read up to it); a bad version or magic is refused from the header alone,
    before the rest, which a pipe may never end (nor a huge file be worth reading)."""
    import threading
    golden = GOLDEN.read_bytes()
    done = threading.Event()
    done.set()                                      # the writers below end at once
    feed_pipe(tmp_path / "tree.pipe", golden, done)
    assert KdTree.load(tmp_path / "tree.pipe") == KdTree.load(GOLDEN)
    for at, value, match in ((8, 4, "version 4"), (0, ord("Q"), "not a kdray tree")):
        data = bytearray(golden)
        data[at] = value
        hold = threading.Event()
        writer = feed_pipe(tmp_path / f"bad{at}.pipe", bytes(data[:layout.HEADER_SIZE]), hold)
        with pytest.raises(TreeFileError, match=match):
            KdTree.load(tmp_path / f"bad{at}.pipe")
        assert writer.is_alive()                    # refused before the pipe ended
        hold.set()
    short = golden[:-1]
    feed_pipe(tmp_path / "short.pipe", short, done)
    with pytest.raises(TreeFileError, match=f"{len(short)} bytes, but its counts need"):
        KdTree.load(tmp_path / "short.pipe")


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


# -- version 3: the object table ----------------------------------------------------------

NAMES = ("floor", "ball, \"B\"", "ünïcode ☃")


def objects_tree(scale=1.0):
    """The golden tree with an object table: input triangles 0, 1, 2 in objects 2, 0, 1."""
    import dataclasses
    tree = dataclasses.replace(two_leaf_tree(), scale=scale)
    return tree.with_objects(np.array([2, 0, 1]), NAMES)


def test_objects_tree_is_version_3(tmp_path):
    """A tree with objects is version 3: version 1's (2's) bytes, the names' length at
    byte 44, the scale at 120, then the objects (u32 per input triangle) and the names'
    compact UTF-8 JSON before the checksum. It reads back equal."""
    import json
    one = two_leaf_tree().to_bytes()
    for scale in (1.0, 2.0 ** -70):
        tree = objects_tree(scale)
        data = tree.to_bytes()
        names = json.dumps(list(NAMES), ensure_ascii=False, separators=(",", ":")).encode()
        assert int.from_bytes(data[8:12], "little") == 3 == layout.VERSION
        assert int.from_bytes(data[44:48], "little") == len(names)
        assert np.frombuffer(data, "<f8", 1, 120)[0] == scale
        assert data[12:44] == one[12:44] and data[48:120] == one[48:120]
        body = len(one) - 16
        assert data[128:body] == one[128:body]
        assert np.frombuffer(data, "<u4", 3, body).tolist() == [2, 0, 1]
        assert data[body + 12:-16] == names
        assert len(data) == layout.file_size(3, 2, 2, 3, len(names))
        assert layout.header_file_size(data[:128]) == len(data)
        path = tmp_path / "t.bin"
        tree.save(path)
        back = KdTree.load(path)
        assert back == tree and back.object_names == NAMES and back.scale == scale
        assert back.objects.dtype == np.uint32 and back.n_objects == 3


def test_trees_of_one_object_stay_version_1_and_2():
    """A table of one object is dropped: the file is the old version's, byte for byte
    (the golden file); a tree with no table reads back with none."""
    import dataclasses
    one = two_leaf_tree().with_objects(np.zeros(3, np.uint8), ("all",))
    assert one.objects is None and one.object_names == () and one.n_objects == 1
    assert one.to_bytes() == GOLDEN.read_bytes()
    scaled = dataclasses.replace(two_leaf_tree(), scale=4.0)
    assert scaled.with_objects([0, 0, 0], ["x"]).to_bytes() == scaled.to_bytes()
    back = KdTree.load(GOLDEN)
    assert back.objects is None and back.object_names == ()
    assert back != objects_tree() and objects_tree() != back


def test_with_objects_checks_the_table():
    from kdray.errors import TreeError
    tree = two_leaf_tree()
    for objects, names, message in [([0, 1], ("a", "b"), r"\(3,\)"),
                                    ([0, 1, 2], ("a", "b"), "out of range"),
                                    ([0, -1, 1], ("a", "b"), "out of range"),
                                    ([0, 1, 1], ("a", "a"), "twice"),
                                    ([0.0, 1.0, 1.0], ("a", "b"), "integers"),
                                    ([0, 1, 1], "ab", "strings"),
                                    ([0, 1, 1], ("a", 2), "strings")]:
        with pytest.raises(TreeError, match=message):
            tree.with_objects(np.array(objects), names)


def _resealed_v3(edit):
    """The objects tree's bytes after an edit, with a valid checksum (a hostile file)."""
    import hashlib
    body = bytearray(objects_tree().to_bytes()[:-layout.CHECKSUM_SIZE])
    edit(body)
    return bytes(body) + hashlib.blake2b(bytes(body), digest_size=layout.CHECKSUM_SIZE).digest()


def test_corrupt_object_table_is_refused(tmp_path):
    data = objects_tree().to_bytes()
    table = len(two_leaf_tree().to_bytes()) - 16              # where the objects start
    for i in range(table, len(data)):                          # the checksum covers it
        bad = bytearray(data)
        bad[i] ^= 0x5A
        with pytest.raises(TreeFileError):
            KdTree.from_bytes(bytes(bad))
    path = tmp_path / "t.bin"
    for cut in (1, 16, 17, 16 + len(NAMES[0]), len(data) - table):
        path.write_bytes(data[:-cut])
        with pytest.raises(TreeFileError, match="truncated|bytes"):
            KdTree.load(path)

    def names(text):
        def edit(b):
            n = int.from_bytes(b[44:48], "little")
            del b[len(b) - n:]
            b += text
            b[44:48] = len(text).to_bytes(4, "little")
        return edit

    def index(value):
        def edit(b):
            b[table:table + 4] = value.to_bytes(4, "little")
        return edit

    def name_bytes(value):
        def edit(b):
            b[44:48] = value.to_bytes(4, "little")
        return edit

    for edit, message in [(names(b'["a","b",'), "not UTF-8 JSON"),
                          (names(b'\xff["a","b"]'), "not UTF-8 JSON"),
                          (names(b'{"a": 1}'), "array of strings"),
                          (names(b'["a", 2, "c"]'), "array of strings"),
                          (names(b'["\\ud800", "b", "c"]'), "Unicode"),
                          (names(b'["a", "a", "c"]'), "unique"),
                          (names(b'["a"]'), "two objects|out of range"),
                          (names(b'[' + b'[' * 100000 + b']' * 100000 + b']'), "JSON"),
                          (index(3), "out of range"),
                          (name_bytes(2**32 - 1), "bytes"),
                          (name_bytes(0), "bytes")]:
        with pytest.raises(TreeFileError, match=message):
            KdTree.from_bytes(_resealed_v3(edit))


def test_hostile_v3_header_is_refused_before_reading(tmp_path):
    """KdTree.load checks the size a version 3 header states (its objects and names
    included) before it reads the body."""
    data = bytearray(objects_tree().to_bytes())
    data[28:32] = (2**32 - 1).to_bytes(4, "little")           # n_input_tris
    path = tmp_path / "t.bin"
    path.write_bytes(bytes(data))
    with pytest.raises(TreeFileError, match="its counts need"):
        KdTree.load(path)
