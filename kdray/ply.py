"""Binary PLY files whose faces are of several sizes, which trimesh's reader refuses
("PLY is unexpected length!"): their vertices and polygons, for kdray.load.

A binary PLY's elements lie one after another, each item's properties in the header's
order; an element of fixed-size properties is one numpy read, one with lists (a count,
then that many indices) is read item by item. Only the vertices' x, y, z and the
faces' vertex_indices (or vertex_index) are kept; every other element and property is
read past.
"""
import struct

import numpy as np

TYPES = {"char": "b", "int8": "b", "uchar": "B", "uint8": "B", "short": "h", "int16": "h",
         "ushort": "H", "uint16": "H", "int": "i", "int32": "i", "uint": "I", "uint32": "I",
         "float": "f", "float32": "f", "double": "d", "float64": "d"}
"""PLY's property types: their struct codes."""

INDEX_NAMES = ("vertex_indices", "vertex_index")


def read_binary_ply(data):
    """(vertices (n, 3) float64, polygons: a list of (k,) int64 index arrays in file
    order) of a binary PLY file's bytes. ValueError for anything else (an ASCII file, a
    header or body it cannot read, no vertex x, y, z)."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError("not a PLY file")
    start = data.index(b"\n", end) + 1
    endian, elements = _header(data[:end].decode("ascii", "replace").splitlines())
    vertices, polygons, at = None, [], start
    for name, count, props in elements:
        if all(kind == "scalar" for kind, *_ in props):
            dtype = np.dtype([(p[1], endian + TYPES[p[2]]) for p in props])
            if dtype.itemsize * count > len(data) - at:
                raise ValueError(f"the file ends inside its {count} {name} elements")
            items = np.frombuffer(data, dtype=dtype, count=count, offset=at)
            at += dtype.itemsize * count
            if name == "vertex":
                vertices = np.column_stack([items[c].astype(np.float64) for c in "xyz"])
            continue
        at = _read_lists(data, at, endian, name, count, props, polygons)
    if vertices is None:
        raise ValueError("no vertex element with x, y and z")
    return vertices, polygons


def _header(lines):
    """(endian '<' or '>', [(element name, count, [("scalar", name, type) or ("list",
    name, count type, item type)])]) of a binary PLY header's lines."""
    endian, elements = None, []
    for line in lines[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) < 2:
                raise ValueError(f"a format line without its format: {line!r}")
            endian = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(words[1])
            if endian is None:
                raise ValueError(f"format {words[1]} is not binary")
        elif words[0] == "element":
            if len(words) < 3 or not words[2].isdigit():
                raise ValueError(f"an element line without its count: {line!r}")
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            if len(words) < (5 if words[1:2] == ["list"] else 3):
                raise ValueError(f"a property line too short: {line!r}")
            if words[1] == "list":
                if words[2] not in TYPES or words[3] not in TYPES:
                    raise ValueError(f"unknown property type in {line!r}")
                elements[-1][2].append(("list", words[4], words[2], words[3]))
            elif words[1] in TYPES:
                elements[-1][2].append(("scalar", words[2], words[1]))
            else:
                raise ValueError(f"unknown property type in {line!r}")
    if endian is None:
        raise ValueError("no binary format line")
    return endian, elements


def _read_lists(data, at, endian, name, count, props, polygons):
    """Read `count` items of an element with list properties from data at `at`; a
    face's index list appended to polygons. Returns where the element ends."""
    sizes = {t: struct.calcsize(endian + c) for t, c in TYPES.items()}
    keep = name == "face"
    for _ in range(count):
        for prop in props:
            if prop[0] == "scalar":
                at += sizes[prop[2]]
                continue
            _, pname, count_type, item_type = prop
            (n,) = struct.unpack_from(endian + TYPES[count_type], data, at)
            at += sizes[count_type]
            if keep and pname in INDEX_NAMES:
                polygons.append(np.array(struct.unpack_from(f"{endian}{n}{TYPES[item_type]}",
                                                             data, at), dtype=np.int64))
            at += n * sizes[item_type]
    if at > len(data):
        raise ValueError("the file ends inside its elements")
    return at
