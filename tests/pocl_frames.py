"""The stack frames of PoCL's compiled packet kernels, per work-item: run as a script
(`python tests/pocl_frames.py`, from the repository's root) it compiles trace_rays (as
`trace` and with STATS) and render_camera with packets of 8 and 16 rays, at the soup
tree's packet stack and at the deepest, into a fresh POCL_CACHE_DIR, and prints JSON:
[{"packet", "packet_stack", "local_size", "kernel", "frame_bytes"}, ...].

PoCL reports 1 KB of private memory for these kernels, so the frame is read from the
compiled work-group function: its largest `sub $imm32, %rsp` (48 81 ec imm32). PoCL runs
a group on one thread, whose stack must hold it (kdray/work_sizes.py, POCL_ITEM_BYTES);
tests/test_runtimes.py checks these frames against that bound."""
import dataclasses
import json
import os
import re
import sys
import tempfile
from pathlib import Path

LOCAL_SIZE = 8
_SUB_RSP = re.compile(rb"\x48\x81\xec(....)", re.S)


def frame_bytes(path):
    """The largest immediate of `sub $imm32, %rsp` in the shared object at `path`, or 0."""
    return max((int.from_bytes(m.group(1), "little") for m in _SUB_RSP.finditer(
        Path(path).read_bytes())), default=0)


def main():
    cache = Path(tempfile.mkdtemp(prefix="kdray-pocl-frames-"))
    os.environ["POCL_CACHE_DIR"] = str(cache)       # before PoCL starts
    os.environ["POCL_KERNEL_CACHE"] = "1"           # the compiled kernels are read there
    root = Path(__file__).resolve().parent
    sys.path[:0] = [str(root), str(root.parent)]
    import numpy as np

    import trees
    from helpers import camera_for, soup
    from kdray.trace import PACKETS, Tracer

    v, f = soup(5)
    tree = trees.split_tree(v, f, max_depth=18, leaf_size=4)
    rng = np.random.default_rng(0)
    o = rng.uniform(-1, 1, (1001, 3))
    d = rng.normal(size=(1001, 3))
    camera = camera_for(tree, 37, 29)
    rows, seen = [], set()
    for packet in PACKETS:
        for deep in (False, True):
            tr = Tracer(tree, device="pocl", packet=packet, local_size=LOCAL_SIZE)
            if deep:
                tr = tr.with_tree(dataclasses.replace(tree, depth=63))
            tr.trace(o, d)
            tr._trace(o, d, stats=True)
            tr.render(camera, ("depth", "normal", "id"))
            for so in sorted(cache.rglob("*.so")):
                if so in seen or f"/{LOCAL_SIZE}-1-1-" not in str(so):
                    continue
                seen.add(so)
                rows.append({"packet": packet, "packet_stack": tr.packet_stack_size,
                             "local_size": LOCAL_SIZE, "kernel": so.stem,
                             "frame_bytes": frame_bytes(so)})
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
