"""TreeCache: built trees on disk, keyed by the geometry and the build parameters, so
that a re-run, or a second job on the same mesh, loads its tree instead of building it.

    cache = TreeCache()                                   # ~/.cache/kdray/trees
    tree, cached = cache.tree(mesh, BuildParams(), build)  # build(mesh, params) on a miss

The key is a BLAKE2b digest of everything a tree depends on: the mesh's float64
vertices and int64 faces, its objects table, the build parameters as given, the tree
file's format version, and the source of the builder and of the tree's layout (a
changed builder never serves an old tree). The objects' table and names are in the
key when the tree keeps them (a mesh of several objects); the file's name and folder
are not: a copy of a mesh elsewhere, or renamed, shares its tree.

Files are tree files (docs/tree-format.md), written atomically, so several processes
(Dask workers) may fill one cache at once: the last rename wins and every reader sees
a whole file. A file that fails to load (corrupt, truncated, another version) is
logged, rebuilt and replaced. Nothing is ever evicted: `kdray cache --clear` or
removing the folder empties it.
"""
import contextlib
import dataclasses
import functools
import hashlib
import logging
import os
from pathlib import Path

import numpy as np

from .errors import OutputError, TreeFileError
from .tree import KdTree

log = logging.getLogger(__name__)

SUFFIX = ".kdt"


def default_folder():
    """The cache's folder: $KDRAY_CACHE_DIR, else $XDG_CACHE_HOME/kdray/trees, else
    ~/.cache/kdray/trees."""
    if os.environ.get("KDRAY_CACHE_DIR"):
        return Path(os.environ["KDRAY_CACHE_DIR"])
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(xdg) / "kdray" / "trees"


@functools.lru_cache(maxsize=1)
def _code_digest():
    """Digest of the source files a tree's content depends on: the builder package,
    the tree and its file layout."""
    here = Path(__file__).parent
    files = sorted((here / "builder").glob("*.py")) + [here / "tree.py", here / "layout.py"]
    h = hashlib.blake2b(digest_size=16)
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.digest()


def tree_key(mesh, params):
    """Hex key (32 characters) of the tree built from `mesh` (kdray.Mesh) with `params`
    (kdray.BuildParams)."""
    from . import layout
    h = hashlib.blake2b(digest_size=16)
    h.update(b"kdray tree %d " % layout.VERSION)
    h.update(_code_digest())
    h.update(repr(sorted(dataclasses.asdict(params).items())).encode())
    for array in (mesh.vertices, mesh.faces):
        a = np.ascontiguousarray(array)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.data)
    if len(mesh.object_names) > 1:     # a tree keeps a table of several objects only
        h.update(np.ascontiguousarray(mesh.objects, dtype="<u4").data)
        h.update(repr(tuple(mesh.object_names)).encode())
    return h.hexdigest()


class TreeCache:
    """A folder of tree files named by `tree_key`.

    folder : None (`default_folder()`) or a path; created when the first tree is stored.
    """

    def __init__(self, folder=None):
        self.folder = Path(default_folder() if folder is None else folder)

    def path(self, key):
        """The file of a key: FOLDER/ab/abcdef....kdt (two-level, so that no folder
        holds more than a few thousand files)."""
        return self.folder / key[:2] / f"{key}{SUFFIX}"

    def load(self, key):
        """The cached KdTree of `key`, or None when there is none or it cannot be read
        (logged)."""
        path = self.path(key)
        if not path.exists():
            return None
        try:
            return KdTree.load(path)
        except TreeFileError as e:
            log.warning("tree cache: %s; building it again", e)
            return None

    def store(self, key, tree):
        """Write `tree` under `key`. A cache that cannot be written is logged, not an
        error: the tree is still used."""
        path = self.path(key)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tree.save(path)
        except (OSError, OutputError) as e:
            log.warning("tree cache: cannot store the tree in %s (%s)", self.folder,
                        getattr(e, "strerror", None) or e)

    def tree(self, mesh, params, build):
        """(tree, cached): the tree of `mesh` with `params` from the cache, or
        build(mesh, params) stored there. cached is True when it came from the file."""
        key = tree_key(mesh, params)
        tree = self.load(key)
        if tree is not None:
            return tree, True
        tree = build(mesh, params)
        self.store(key, tree)
        return tree, False

    def _files(self):
        """(trees, leftovers): the cache's tree files, and the temporary files of
        writes that a killed process left (kdray.files.atomic_write's `.NAME.<hex>.tmp`),
        which nothing reads."""
        return (list(self.folder.glob(f"??/*{SUFFIX}")),
                list(self.folder.glob(f"??/.*{SUFFIX}.*.tmp")))

    def clear(self):
        """Remove every cached tree, the leftovers of writes cut short and the emptied
        folders (a run that fills the cache meanwhile may lose a tree it was writing:
        it is logged and built again next time); returns (trees, bytes) removed.
        OutputError, after removing what it can, when a file stays (a read-only or
        immutable folder): the cache is not empty."""
        trees, leftovers = self._files()
        files = size = 0
        kept = []
        for path in trees + leftovers:
            try:
                bytes_ = path.stat().st_size
                path.unlink()
                size += bytes_
                files += path.suffix == SUFFIX
            except FileNotFoundError:
                pass                                # removed meanwhile by another run
            except OSError as e:
                kept.append((path, e))
        for folder in self.folder.glob("??"):
            with contextlib.suppress(OSError):
                folder.rmdir()                      # only when empty
        if kept:
            path, e = kept[0]
            raise OutputError(f"cannot empty the tree cache {self.folder}: {len(kept)} file(s) "
                              f"stay, {path.name} ({e.strerror or e}); removed {files} "
                              f"tree(s)")
        return files, size

    def usage(self):
        """(trees, bytes) in the cache, the leftovers of writes cut short in the bytes."""
        trees, leftovers = self._files()
        size = 0
        for path in trees + leftovers:
            with contextlib.suppress(OSError):
                size += path.stat().st_size
        return len(trees), size
