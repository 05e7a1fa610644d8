"""Hits: the nearest hits of N rays, as `Tracer.trace` returns them.

Arrays returned (for (N, 3) rays; rays shaped (..., 3) give arrays of their shape
(...) and normal (..., 3))::

    Hits.t       (N,) float32     ray parameter in units of |direction|; +inf on a miss
    Hits.prim    (N,) uint32      input triangle id; 0xFFFFFFFF on a miss
    Hits.u, .v   (N,) float32     P = (1 - u - v) v0 + u v1 + v v2; 0 on a miss
                                  (strided views of one (N, 2) array)
    Hits.normal  (N, 3) float32   unit geometric normal (v1 - v0) x (v2 - v0); 0 on a miss
    Hits.object  (N,) uint32      the hit triangle's object (KdTree.objects; 0 for a
                                  tree with no table); 0xFFFFFFFF on a miss. Looked up
                                  on first access

u, v and normal are None when `trace` was asked to leave them out (outputs=).

With precision="double", t, u and v are float64 (kdray.double).
"""
import dataclasses
import functools

import numpy as np

from .errors import KdrayError
from .layout import MISS
from .tree import object_ids

TRACE_OUTPUTS = ("uv", "normal")
"""What `Tracer.trace` computes besides t and prim when asked (all by default)."""


def kernel_outputs(outputs, double=False):
    """The kernel outputs ("UV", "NORMAL") of `Tracer.trace`'s `outputs` (names from
    TRACE_OUTPUTS, or one name); without "UV" where double precision recomputes u, v
    on the host. KdrayError for anything else."""
    if isinstance(outputs, str):
        outputs = (outputs,)
    try:
        unknown = sorted(map(repr, set(outputs) - set(TRACE_OUTPUTS)))
    except TypeError:                         # None, a number: no names
        raise KdrayError(f"outputs must be names from {list(TRACE_OUTPUTS)}, got "
                         f"{outputs!r:.60}") from None
    if unknown:
        raise KdrayError(f"unknown trace outputs [{', '.join(unknown)}]: choose from "
                         f"{list(TRACE_OUTPUTS)} (t and prim always)")
    return tuple(name.upper() for name in outputs if not (double and name == "uv"))


class TriangleAnswers:
    """What answers naming a triangle a row (`prim`, MISS where none, and the tree's
    `object_table`: Hits, points.ClosestPoints) share: `hit` and `object`."""

    @property
    def hit(self):
        """bool, prim's shape: the row names a triangle (a ray's hit, a point's nearest
        surface point within the distance asked)."""
        return self.prim != MISS

    @functools.cached_property
    def object(self):
        """uint32, prim's shape: the object of each row's triangle, 0xFFFFFFFF where none;
        computed on first access (kdray.tree.object_ids)."""
        return object_ids(self.prim, self.object_table)


@dataclasses.dataclass(eq=False)
class Hits(TriangleAnswers):
    """Nearest hits of N rays (see the module docstring for the arrays).

    object_table : the traced tree's KdTree.objects ((n_input_tris,) uint32, or None:
        one object), which `object` looks up prim in."""

    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    normal: np.ndarray
    object_table: np.ndarray = dataclasses.field(default=None, repr=False)

    def __len__(self):
        return len(self.t)

    def _reshaped(self, shape):
        """The same hits as arrays of `shape` (the rays' shape; normal shape + (3,)):
        views where numpy can make them."""
        def part(a, tail=()):
            return None if a is None else a.reshape(shape + tail)

        return Hits(part(self.t), part(self.prim), part(self.u), part(self.v),
                    part(self.normal, (3,)), object_table=self.object_table)

    def __getitem__(self, index):
        """The hits of a subset of the rays (a slice, mask or index array)."""
        def part(a):
            return None if a is None else a[index]

        # a ray's normal is a row of 3: the rays' index, then all of it (an Ellipsis in
        # the index stands for the rays' axes only, not the row's)
        rays = index if isinstance(index, tuple) else (index,)
        row = rays + ((slice(None),) if any(i is Ellipsis for i in rays) else (Ellipsis,))
        normal = None if self.normal is None else self.normal[row]
        return Hits(self.t[index], self.prim[index], part(self.u), part(self.v),
                    normal, object_table=self.object_table)
