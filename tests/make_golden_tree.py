"""Regenerate tests/data/tree_v1.bin, the golden bytes of the tree file format.

Run only when the format version changes on purpose: python tests/make_golden_tree.py"""
from pathlib import Path

from small_trees import two_leaf_tree

if __name__ == "__main__":
    two_leaf_tree().save(Path(__file__).parent / "data" / "tree_v1.bin")
