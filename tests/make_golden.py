"""Regenerate tests/golden/*.exr on purpose (`make golden`); review before committing."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from golden_scenes import GOLDEN, cameras, render  # noqa: E402

from kdray.images import write_exr  # noqa: E402

if __name__ == "__main__":
    GOLDEN.mkdir(exist_ok=True)
    for name in cameras():
        write_exr(GOLDEN / f"{name}.exr", render(name))
        print(f"wrote {GOLDEN / (name + '.exr')}")
