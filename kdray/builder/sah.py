"""The SAH sweep: the cheapest split plane of one node (Wald & Havran 2006, Alg. 1, 3).

Cost of splitting a node V with a plane p (K_T, K_I, lambda = empty_bonus)::

    C(p) = lambda * (K_T + K_I * (P_L N_L + P_R N_R)),   P_X = SA(V_X) / SA(V)

with lambda applied only when one side gets no triangle. Triangles lying in p
(PLANAR) are tried on either side and the cheaper is kept. Only planes strictly
inside the node's box are evaluated: a boundary plane has an empty side with no
volume, and would let the build split empty slabs forever. A node flat along one
axis (e.g. a mesh lying in z = 0) has no candidate there and a positive area from
the other two axes.

Numba-compiled (`cache=True`; the first call compiles).
"""
import numpy as np
from numba import carray, njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from .events import END, PLANAR, START, key_bits, key_kind, position_bits, position_value

SWEEP_BLOCK = 32
"""Events per block of the sweep's bound test (`best_split`): with the longest axis
swept first most blocks are skipped, and longer ones skip more per test (16 and 64
were slower, BENCHMARKS.md)."""

SMALL_RUN = 256
"""Runs of at most this many events (nodes of up to 128 triangles) are swept without
the block bounds, in passes over scratch arrays on the stack (`_sweep_small`): in a
small node the group loop's exit, one mispredicted branch per position, costs more
than the bound test saves (128 and 512 were slower, BENCHMARKS.md)."""

LEFT = 0
"""Planar triangles at the chosen plane go to the below (left) child..."""
RIGHT = 1
"""...or to the above (right) child."""


@njit(cache=True, inline="always")
def sah_cost(p_left, p_right, n_left, n_right, K_T, K_I, empty_bonus):
    """C = lambda (K_T + K_I (P_L N_L + P_R N_R)), lambda = empty_bonus when a side
    holds no triangles (W&H; P_L, P_R relative to the node's surface area)."""
    c = K_T + K_I * (p_left * n_left + p_right * n_right)
    if n_left == 0 or n_right == 0:
        c *= empty_bonus
    return c


@njit(cache=True, inline="always")
def _wins(c, best_cost, tie_wins):
    """Whether a plane of cost c replaces the best so far: cheaper, or as cheap while
    tie_wins (a lower axis's plane against a higher one's swept before it)."""
    return c < best_cost or (tie_wins and c == best_cost)


@intrinsic
def _stack_scratch(typingctx, dtype):
    """A pointer to SMALL_RUN elements of `dtype` on the calling function's stack (an
    alloca in its entry block: no allocation per call); wrap it with numba.carray."""
    dt = dtype.dtype

    def codegen(context, builder, sig, args):
        return cgutils.alloca_once(builder, context.get_data_type(dt), size=SMALL_RUN)
    return types.CPointer(dt)(dtype), codegen


@njit(cache=True, inline="always")
def _sweep_small(buf, start, end, n_tris, k, lo, hi, lo_bits, hi_bits, cap, perim,
                 K_T, K_I, empty_bonus, best, s_bits, s_left, s_right, s_planar, s_cost):
    """Sweep one run buf[start:end] of at most SMALL_RUN events; `best` is best_split's
    (cost, axis, position, side, n_left, n_right) so far, returned updated.

    s_* : (SMALL_RUN,) scratch (uint64, int64, int64, int64, float64).
    Pass 1 counts, one position (group of equal bits) per slot: every event writes
    its group's slot and the slot advances after the group's last event, so the
    loop has no branch on the events. Pass 2 costs every position (LEFT), a loop
    LLVM vectorizes. Pass 3 keeps the first cheapest, in best_split's order."""
    best_cost = best[0]
    tie_wins = k < best[1]                          # a tie with a higher axis's plane
    u_last = np.uint64(end - 1)
    g = np.uint64(0)
    n_left = 0
    n_right = n_tris
    g_left = 0
    g_planar = 0
    planars = 0
    prev_bits = np.uint64(1) << np.uint64(40)       # no position's bits
    for q in range(np.uint64(start), np.uint64(end)):
        key = buf[q]
        bits = key_bits(key)
        kind = key_kind(key)
        new = bits != prev_bits
        prev_bits = bits
        g_left = n_left if new else g_left              # N_L before this position
        g_planar = (0 if new else g_planar) + (kind & 1)
        planars += kind & 1
        n_left += (kind + 1) >> 1                       # START and PLANAR
        n_right -= 1 - (kind >> 1)                      # END and PLANAR
        s_bits[g] = bits
        s_left[g] = g_left + g_planar                   # planar triangles left
        s_right[g] = n_right
        s_planar[g] = g_planar
        nxt = key_bits(buf[min(q + np.uint64(1), u_last)])
        g += np.uint64((q == u_last) | (nxt != bits))
    for h in range(g):
        bits = s_bits[h]
        x = np.float64(position_value(bits))
        c = sah_cost(cap + (x - lo) * perim, cap + (hi - x) * perim, s_left[h], s_right[h],
                     K_T, K_I, empty_bonus)
        s_cost[h] = c if (lo_bits < bits) & (bits < hi_bits) else np.inf
    found = g                                       # none
    side = LEFT
    if planars == 0:
        for h in range(g):
            if _wins(s_cost[h], best_cost, tie_wins):
                best_cost = s_cost[h]
                found = h
                tie_wins = False
    else:
        for h in range(g):
            if _wins(s_cost[h], best_cost, tie_wins):
                best_cost = s_cost[h]
                found = h
                side = LEFT
                tie_wins = False
            bits = s_bits[h]
            if s_planar[h] > 0 and lo_bits < bits and bits < hi_bits:    # planar right
                x = np.float64(position_value(bits))
                c = sah_cost(cap + (x - lo) * perim, cap + (hi - x) * perim,
                             s_left[h] - s_planar[h], s_right[h] + s_planar[h],
                             K_T, K_I, empty_bonus)
                if _wins(c, best_cost, tie_wins):
                    best_cost = c
                    found = h
                    side = RIGHT
                    tie_wins = False
    if found == g:
        return best
    pos = np.float32(np.float64(position_value(s_bits[found])))
    if side == LEFT:
        return best_cost, k, pos, LEFT, s_left[found], s_right[found]
    return (best_cost, k, pos, RIGHT, s_left[found] - s_planar[found],
            s_right[found] + s_planar[found])


@njit(cache=True)                       # not BORROW (jit.py): carray needs numba's NRT
def best_split(buf, off, counts, n_tris, box, K_T, K_I, empty_bonus, max_cost=np.inf):
    """Sweep the node's three sorted event runs.

    buf[off:] : the node's events (x run, y run, z run; `counts` (3,) long);
    n_tris : triangles in the node;  box : (2, 3) float64 (float32 values);
    max_cost : only planes that cost at most this are looked for (the builder passes
    the leaf's cost K_I * n_tris: a dearer plane makes a leaf anyway; then most blocks
    of a node that becomes a leaf are only counted).
    Returns (cost, axis, position float32, side LEFT/RIGHT for planar triangles,
    n_left, n_right triangles on each side); axis is -1 and cost inf when no plane
    lies strictly inside the box or none costs at most max_cost.
    Ties keep the first found: lower axis, lower position, planar triangles left
    (the axes are swept longest first, and a lower axis's plane wins a tie).

    The events go in blocks of about SWEEP_BLOCK (whole positions). Once a cost is
    known, a block is first bounded from below: its first position's P_L, its last
    position's P_R, the left count before it and the right count after it (both
    counts only grow inside the block; lambda if either is zero). Every operation of
    the cost is monotone under rounding, so each plane in the block costs, in
    float64, at least the bound: a block whose bound is not below the best cost is
    only counted, and the result is exactly that of evaluating every plane.
    """
    ext0 = box[1, 0] - box[0, 0]
    ext1 = box[1, 1] - box[0, 1]
    ext2 = box[1, 2] - box[0, 2]
    area = 2.0 * (ext0 * ext1 + ext1 * ext2 + ext2 * ext0)
    best_cost = np.nextafter(max_cost, np.inf)      # c < best_cost: c <= max_cost
    best_axis = -1
    best_pos = np.float32(0.0)
    best_side = LEFT
    best_left = 0
    best_right = 0
    if not area > 0.0:
        return np.inf, best_axis, best_pos, best_side, best_left, best_right
    inv_area = 1.0 / area
    s_bits = carray(_stack_scratch(np.uint64), SMALL_RUN)
    s_left = carray(_stack_scratch(np.int64), SMALL_RUN)
    s_right = carray(_stack_scratch(np.int64), SMALL_RUN)
    s_planar = carray(_stack_scratch(np.int64), SMALL_RUN)
    s_cost = carray(_stack_scratch(np.float64), SMALL_RUN)
    # The longest axis first: its best plane, usually the node's, then bounds the
    # other two's blocks. Ties still go to the lower axis (tie_wins), so the result
    # is that of sweeping x, y, z in order.
    first = 0
    if ext1 > ext0:
        first = 1
    if ext2 > max(ext0, ext1):
        first = 2
    for kk in range(3):
        k = (first + kk) % 3
        start = off
        for j in range(k):
            start += counts[j]
        end = start + counts[k]
        lo = box[0, k]
        hi = box[1, k]
        lo_bits = position_bits(lo)
        hi_bits = position_bits(hi)
        e1 = box[1, (k + 1) % 3] - box[0, (k + 1) % 3]
        e2 = box[1, (k + 2) % 3] - box[0, (k + 2) % 3]
        cap = 2.0 * e1 * e2 * inv_area              # P of a zero-width slab
        perim = 2.0 * (e1 + e2) * inv_area          # dP / dx
        if counts[k] <= SMALL_RUN:
            (best_cost, best_axis, best_pos, best_side, best_left, best_right) = _sweep_small(
                buf, start, end, n_tris, k, lo, hi, lo_bits, hi_bits, cap, perim, K_T, K_I,
                empty_bonus, (best_cost, best_axis, best_pos, best_side, best_left, best_right),
                s_bits, s_left, s_right, s_planar, s_cost)
            continue
        tie_wins = k < best_axis
        n_left = 0
        n_right = n_tris
        i = start
        while i < end:
            # A block of about SWEEP_BLOCK events, ending where the position changes.
            j = min(i + SWEEP_BLOCK, end)
            last_bits = key_bits(buf[j - 1])
            while j < end and key_bits(buf[j]) == last_bits:
                j += 1
            if best_cost < np.inf:
                # The block's lower bound: no plane in it can cost less (see above).
                # (kind: END 0, PLANAR 1, START 2; unsigned indices, so that numba adds
                # no negative-index test and the loop vectorizes)
                b_planar = 0
                b_start = 0
                for q in range(np.uint64(i), np.uint64(j)):
                    kind = key_kind(buf[q])
                    b_planar += kind & 1
                    b_start += kind >> 1
                n_right_after = n_right - (j - i - b_start)      # END and PLANAR leave
                x_first = np.float64(position_value(key_bits(buf[i])))
                x_last = np.float64(position_value(last_bits))
                bound = sah_cost(cap + (x_first - lo) * perim, cap + (hi - x_last) * perim,
                                 n_left, n_right_after, K_T, K_I, empty_bonus)
                if bound > best_cost or (bound == best_cost and not tie_wins):
                    n_left += b_start + b_planar
                    n_right = n_right_after
                    i = j
                    continue
            while i < j:
                # Count the events at this position (one group of equal position bits).
                key = buf[np.uint64(i)]
                bits = key_bits(key)
                p_end = 0
                p_planar = 0
                p_start = 0
                while True:
                    kind = key_kind(key)
                    p_end += kind == END
                    p_planar += kind == PLANAR
                    p_start += kind == START
                    i += 1
                    if i >= j:
                        break
                    key = buf[np.uint64(i)]
                    if key_bits(key) != bits:
                        break
                # Errata 2: N_P = p_planar; N_R -= p_planar + p_end; evaluate; N_L += ...
                n_right -= p_end + p_planar
                if lo_bits < bits and bits < hi_bits:
                    x = np.float64(position_value(bits))
                    p_left = cap + (x - lo) * perim
                    p_right = cap + (hi - x) * perim
                    # planar triangles on the left
                    n_l = n_left + p_planar
                    c = sah_cost(p_left, p_right, n_l, n_right, K_T, K_I, empty_bonus)
                    if _wins(c, best_cost, tie_wins):
                        best_cost, best_axis, best_pos, best_side = c, k, np.float32(x), LEFT
                        best_left, best_right = n_l, n_right
                        tie_wins = False
                    if p_planar > 0:                    # ... and on the right
                        n_r = n_right + p_planar
                        c = sah_cost(p_left, p_right, n_left, n_r, K_T, K_I, empty_bonus)
                        if _wins(c, best_cost, tie_wins):
                            best_cost, best_axis, best_pos, best_side = c, k, np.float32(x), RIGHT
                            best_left, best_right = n_left, n_r
                            tie_wins = False
                n_left += p_start + p_planar
    if best_axis < 0:
        best_cost = np.inf
    return best_cost, best_axis, best_pos, best_side, best_left, best_right
