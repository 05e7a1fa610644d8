"""How much work a Tracer's kernels take at once: the stack sizes programs are compiled
for, the rays a work-item traces together (packets), the work-group and batch sizes,
and PoCL's bound on a work-group (a thread's stack). kdray.trace's Tracer picks its
options from these."""
from . import device as _device
from .layout import MAX_DEPTH_LIMIT


STACK_SIZES = (8, 16, 32, MAX_DEPTH_LIMIT)
"""The stack sizes a Tracer compiles by default: every tree whose depth + 1 fits in one
of them shares its program (a program build takes seconds on some runtimes), for at
most twice the private memory a ray needs."""


def default_stack_size(tree):
    """The smallest of STACK_SIZES that holds tree.depth + 1 entries (a ray never needs
    more): 8, 16, 32 or 64."""
    need = int(tree.depth) + 1
    return next((size for size in STACK_SIZES if size >= need), MAX_DEPTH_LIMIT)


PACKETS = (8, 16)
"""Rays per work-item in packet mode: the lanes of one vector register (kernels/lanes.h),
8 floats with AVX2, 16 with AVX-512."""


def default_packet(device):
    """Rays per work-item: on CPU devices a packet as wide as the device's native float
    vector (16 on AVX-512, else 8), 1 on others.

    CPU runtimes run a work-item's traversal loop scalar (a data-dependent loop does not
    vectorize across work-items), so on a CPU coherent rays share one work-item in
    vector lanes. A GPU already runs work-items in lock-step (SIMT): one ray each.
    """
    if not _device.is_cpu(device):
        return 1
    width = int(getattr(device, "native_vector_width_float", 0) or 0)
    return max(p for p in PACKETS if p <= max(width, PACKETS[0]))


def default_work_sizes(device, packet=1):
    """(local_size, batch_size, groups) for a device and rays per work-item.

    CPU (PoCL, Intel's runtime): a work-group runs on one thread, its work-items one
    after another, and a traversal loop does not vectorize across them; small groups
    keep the per-group barrier cheap and many groups (4 per core) balance the load
    through the counter; a batch is 16 rounds of the group (with packets of 16, 2048
    rays: four 64 x 8 render tiles, and for trace a run of 512 image columns, whose
    rows the rays are read along). On PoCL the size makes no difference from 1 to 16
    work-items; Intel's runtime vectorizes a group as wide as its vector unit (8 with AVX2, 16 with
    AVX-512) across work-items, which makes single rays in lockstep slower
    (bench/tune_work_sizes.py, BENCHMARKS.md); packet kernels tell it not to
    (render.cl, KD_VEC_HINT).
    GPU: 64 work-items (two warps / one wavefront), batches of 4 rays each, and about
    one full device of resident groups.
    """
    cu = max(int(device.max_compute_units), 1)
    if _device.is_cpu(device):
        local = 8
        return local, 16 * local * packet, 4 * cu
    local = min(64, int(device.max_work_group_size))
    return local, 4 * local * packet, 16 * cu


POCL_ITEM_BYTES = (2560, 44)
"""PoCL keeps the private data of each work-item of a group on the stack of the thread
that runs the group, and a packet kernel's is large (the lanes' vectors, the packet's
stack): a group that does not fit overflows it, and a frame larger than the stack can
step over the guard page into other memory instead of crashing. A bound on one
work-item's bytes with packets of P rays and a packet stack of S entries:
P (2560 + 44 S): about twice the frames of PoCL's compiled kernels (BENCHMARKS.md; 12.9
and 18.2 KiB a work-item with P = 8, 22.5 and 32.2 KiB with P = 16, at S = 16 and 64;
tests/test_runtimes.py checks the compiled frames against it), measured before the
wide walks (two rays' stacks, 12 bytes an entry, 7 entries a level of wide nodes),
which PoCL 3.0 has not compiled since (it fails its probe on the AVX-512 CPUs here)."""

POCL_STACK_RESERVE = 256 << 10
"""Bytes of a thread's stack not counted for work-items: glibc's static TLS (carved from
the top of the stack, larger the more libraries a process loads) and PoCL's own frames."""


def thread_stack_bytes():
    """The stack of a thread started with default attributes, as glibc sizes it: the
    soft RLIMIT_STACK (8 MiB on most systems), or 2 MiB where that is unlimited."""
    try:
        import resource
        soft = resource.getrlimit(resource.RLIMIT_STACK)[0]
    except (ImportError, OSError, ValueError):
        return 2 << 20
    return 2 << 20 if soft == resource.RLIM_INFINITY or soft <= 0 else int(soft)


def max_local_size(device, packet, packet_stack_size):
    """The largest work-group a Tracer takes on `device`: its max_work_group_size, and
    on PoCL with packets (packet > 1) no more work-items than a thread's stack holds
    (`pocl_item_bytes` each, `thread_stack_bytes` less POCL_STACK_RESERVE)."""
    limit = int(device.max_work_group_size)
    if packet > 1 and _device.implementation(device) == "pocl":
        limit = min(limit, max((thread_stack_bytes() - POCL_STACK_RESERVE)
                               // pocl_item_bytes(packet, packet_stack_size), 1))
    return limit


def pocl_item_bytes(packet, packet_stack_size):
    """POCL_ITEM_BYTES: the stack bytes a work-item of a packet kernel is allowed on PoCL."""
    return packet * (POCL_ITEM_BYTES[0] + POCL_ITEM_BYTES[1] * packet_stack_size)
